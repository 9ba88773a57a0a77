"""The training curves (the paper's Fig. 5) and what the report says of them."""

import csv

import numpy as np
import pytest
from PIL import Image

from safeswitch.report.training import collision_steps, training_curves, training_story
from safeswitch.training.callbacks import PROGRESS_FIELDS


def write_progress(path, rows):
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=PROGRESS_FIELDS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: row.get(k, "") for k in PROGRESS_FIELDS})


def rollout(step, ret, cut=0.0, safety=0.0, speed=400.0, accel_lat=500.0):
    return {"timesteps": step, "return": ret, "adas": -25.0 * 20 * safety, "lka": 550.0,
            "speed": speed, "accel_lon": 480.0, "accel_lat": accel_lat, "cut_rate": cut,
            "activation_episode_rate": safety}  # fmt: skip


def test_the_story_reads_its_numbers_off_the_progress_log(tmp_path):
    """Each statement beside the paper's is computed from the log: first and last tenths,
    the drops in return (and those with more safety episodes), the early speed peak and
    lateral low, and the first rollout in which a fifth of the episodes cut in front."""
    rows = [rollout(1000 * (k + 1), 1500.0 + 10 * k) for k in range(40)]
    rows[1] |= {"speed": 900.0}  # the early speed peak (first fifth: rollouts 0-7)
    rows[3] |= {"accel_lat": 100.0}  # the early lateral low
    rows[20] |= {"return": 1000.0, "activation_episode_rate": 0.3}  # a drop with safety
    rows[30] |= {"return": 1200.0}  # a drop without
    for k in range(25, 40):
        rows[k]["cut_rate"] = 0.35  # rolling mean of 10: below 20 % up to rollout 29, not after
    rows.insert(5, {"timesteps": 5500, "return": ""})  # a rollout that finished no episode
    path = tmp_path / "progress.csv"
    write_progress(path, rows)
    story = dict(training_story(path))
    texts = list(story.values())
    assert "1,515 → 1,875" in texts[0]  # means of rollouts 0-3 and 36-39
    assert "more than 10 % from one rollout to the next 2 times, 1 of them" in texts[0]
    assert "peaks at step 2,000 (900)" in texts[2] and "lowest at step 4,000 (100)" in texts[2]
    assert "stays at 20 % or more from step 31,000 on; 35% in the last tenth" in texts[4]
    assert "lowest at step 1,000 (0%" in texts[4]
    training_curves(path, tmp_path / "curves.png", title="test")
    with Image.open(tmp_path / "curves.png") as image:
        assert image.size[0] > 800 and image.size[1] > 800  # eight panels


def test_a_log_without_finished_episodes_is_refused_by_name(tmp_path):
    path = tmp_path / "progress.csv"
    write_progress(path, [{"timesteps": 100, "return": ""}])
    with pytest.raises(ValueError, match=r"progress\.csv has no finished episodes"):
        training_story(path)


def test_the_curves_mark_every_rollout_in_which_training_collided(tmp_path):
    """A figure that leaves out a collision is a defect: the running total's increments are
    the collisions, the rollout that finished no episode included."""
    rows = [rollout(1000 * (k + 1), 1500.0) | {"collisions_total": 0} for k in range(10)]
    rows[3]["collisions_total"] = 2
    rows[4]["collisions_total"] = rows[5]["collisions_total"] = 2
    rows[6] = {"timesteps": 7000, "return": "", "collisions_total": 3}
    rows[7]["collisions_total"] = rows[8]["collisions_total"] = rows[9]["collisions_total"] = 3
    path = tmp_path / "progress.csv"
    write_progress(path, rows)
    assert collision_steps(path) == [(4000, 2), (7000, 1)]
    training_curves(path, tmp_path / "curves.png")
    write_progress(path, [rollout(1000, 1500.0)])  # a log without the running total
    assert collision_steps(path) == []


def test_any_other_plants_log_is_drawn_with_its_declared_failures_marked(tmp_path):
    """``training.generic``'s log (no reward terms): return, the Safety controller's share of
    steps and the failures the plant declares, each failing rollout on the rug — the one
    that finished no episode too."""
    from safeswitch.training.generic import PROGRESS_FIELDS as PLANT_FIELDS

    rows = [{"timesteps": 512 * (k + 1), "episodes": 4 * (k + 1), "failures_total": 0,
             "activation_rate": 0.1, "failure_rate": 0.0, "return": 90.0 + k}
            for k in range(8)]  # fmt: skip
    rows[2] |= {"failures_total": 1, "failure_rate": 0.25}
    rows[3] = {"timesteps": 2048, "failures_total": 3, "activation_rate": 0.2}  # no episode ended
    for row in rows[4:]:
        row["failures_total"] = 3
    path = tmp_path / "progress.csv"
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=PLANT_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    assert collision_steps(path) == [(1536, 1), (2048, 2)]
    training_curves(path, tmp_path / "curves.png", title="plant")
    with Image.open(tmp_path / "curves.png") as image:
        assert image.size[0] < 800 < image.size[1]  # three panels, one above the other


def selected_pixels(png):
    """Pixels of the selection line's green (antialiased: green well above red and blue; no
    curve is drawn in a green)."""
    rgb = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    return np.argwhere(rgb[:, :, 1] - np.maximum(rgb[:, :, 0], rgb[:, :, 2]) > 40)


def test_the_curves_mark_the_policy_the_run_kept(tmp_path):
    """The curves run to the end of training; a run that chose its policy on validation says
    where that policy is: a vertical line at its step across the panels, and only then."""
    rows = [rollout(1000 * (k + 1), 1500.0 + k) for k in range(20)]
    path = tmp_path / "progress.csv"
    write_progress(path, rows)
    training_curves(path, tmp_path / "plain.png")
    training_curves(path, tmp_path / "kept.png", selected=6000)
    assert len(selected_pixels(tmp_path / "plain.png")) == 0
    marked = selected_pixels(tmp_path / "kept.png")
    columns = np.unique(marked[:, 1])
    height = Image.open(tmp_path / "kept.png").size[1]
    assert len(columns) < 60  # a vertical line (and its legend entry), not a curve
    assert np.ptp(marked[:, 0]) > height / 2  # down through the panels


def test_a_run_draws_the_line_at_the_policy_its_metrics_say_it_kept(tmp_path):
    import json

    from safeswitch.app.train import kept_step

    assert kept_step(tmp_path) is None  # no metrics.json yet
    (tmp_path / "metrics.json").write_text(json.dumps({"selected": None}))
    assert kept_step(tmp_path) is None  # no validation
    kept = {"selected": {"best_timesteps": 81920}, "refined": {"selected_iteration": 0}}
    (tmp_path / "metrics.json").write_text(json.dumps(kept))
    assert kept_step(tmp_path) == 81920
    kept["refined"]["selected_iteration"] = 2  # the refinement replaced PPO's policy
    (tmp_path / "metrics.json").write_text(json.dumps(kept))
    assert kept_step(tmp_path) is None
