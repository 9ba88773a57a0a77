"""What limits the traffic go predictor: what it is not shown, or how many samples it learns
from? (issue #39; docs/learning_experiments.md, "What limits the go predictor in traffic").

A one-off probe. Random drivers (``go_predictor.RandomDrivers``) on the recipe's own scene
(``experimental/traffic_certified_go_scene``: the shipped recipe without a predictor in its
observation), scene seeds 7801 and 7901 (the first batches of ``go_model_scene``), every
decision before the first conflict zone labelled with the gap planner's go check, as
``go_predictor.py`` samples. Beside the observation each sample records, for the four
conflicting vehicles the observation shows (in its order), what the observation leaves out:
the acceleration its driver last decided on, its desired speed, how long it has waited at the
junction, whether it yields to the ego, and how far below its desired speed it drives. The
same MLP (2 x 128, 30 epochs) is fitted on the observation, the observation and the
accelerations, and the observation and all five; then on the observation with a quarter and
half of the training episodes (the held-out episodes the same), for the learning curve.

Run: ``python experiments/probe_go_information.py`` (one torch thread; about 70 s of sampling
and 1-2 minutes per fit).
"""

from __future__ import annotations

import json

import numpy as np
import torch
from go_predictor import fit, samples

from safeswitch.leftturn.config import traffic_config
from safeswitch.leftturn.traffic import _soonest_conflicts
from safeswitch.training.config import load_config

CONFIG = "experimental/traffic_certified_go_scene"
SEEDS = (7801, 7901)
EPISODES = 1024
#: What the observation leaves out, per observed conflicting vehicle.
HIDDEN = ("accel", "desired", "waited", "yields", "below_desired")


def hidden(task, state) -> np.ndarray:
    """:data:`HIDDEN` of the conflicting vehicles the observation shows, in its order
    ``[B, K * len(HIDDEN)]`` (the north car, column 0 of the view: its speed in the scenario
    as its desired speed, the rest 0)."""
    view, traffic = task.view(state), state.traffic
    batch, columns = view.present.shape
    k, width = task.traffic.observed, len(HIDDEN)
    extra = np.zeros((batch, columns, width))
    extra[:, 1:] = np.stack(
        [traffic.accel, traffic.desired, traffic.waited, traffic.yields,
         traffic.desired - traffic.speed], axis=-1,
    )  # fmt: skip
    extra[:, 0, 1] = state.scenarios.north_speed
    out = np.zeros((batch, 6 + (6 + width) * k), dtype=np.float32)
    _soonest_conflicts(view.present, view.ego_progress, view.ego_cert_zone, view.other_progress,
                       view.other_cert_zone, view.other_speed, extra, k, out)  # fmt: skip
    return np.concatenate([out[:, 12 + (6 + width) * n : 12 + (6 + width) * n + width]
                           for n in range(k)], axis=1)  # fmt: skip


def held_out(x: np.ndarray, y: np.ndarray, g: np.ndarray) -> dict:
    """The held-out scores of ``go_predictor.fit``'s MLP (2 x 128, 30 epochs)."""
    scores = fit(x, y, g, 30, SEEDS[0], 128)["scores"]
    return {name: {key: round(value, 5) for key, value in part.items()
                   if isinstance(value, float)} for name, part in scores.items()}  # fmt: skip


def main() -> None:
    torch.set_num_threads(1)
    parts = [samples(CONFIG, seed, EPISODES, extra=hidden) for seed in SEEDS]
    x = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    g = np.concatenate([p[2] + b * EPISODES for b, p in enumerate(parts)])
    traffic = traffic_config(load_config(CONFIG).traffic)
    assert traffic is not None
    per = len(HIDDEN)  # the hidden columns follow the observation, per observed vehicle
    width = x.shape[1] - per * traffic.observed
    accel = [width + n * per for n in range(traffic.observed)]
    print(
        f"{len(y):,} samples of {g.max() + 1:,} episodes, {y.mean():.1%} of them a go", flush=True
    )
    for name, columns in (("observation", list(range(width))),
                          ("and the accelerations", list(range(width)) + accel),
                          ("and all five", list(range(x.shape[1])))):  # fmt: skip
        print(name, json.dumps(held_out(x[:, columns], y, g)), flush=True)
    held = np.random.default_rng(SEEDS[0]).random(g.max() + 1) < 0.2
    for share in (0.25, 0.5):
        keep = (held | (np.random.default_rng(0).random(g.max() + 1) < share))[g]
        scores = held_out(x[keep][:, :width], y[keep], g[keep])
        print(f"observation, {share:.0%} of the training episodes", json.dumps(scores), flush=True)


if __name__ == "__main__":
    main()
