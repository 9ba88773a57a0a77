"""``safeswitch demo``: the framework on the embedded simulator, end to end, printed.

The rule-based system (``PID_th`` under the paper's switching logic) and the shipped PPO policy
in the three Section VI scenarios, and a reckless learned controller (full throttle) over 1,000
random scenarios with and without the switching logic. Pictures (a strip of top-down frames per
scenario) and ``summary.json`` go to the output folder. (``safeswitch reproduce --quick``, the
full report, is planned.)
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from safeswitch.evaluation.policies import load_policy
from safeswitch.leftturn.config import LeftTurnConfig, resolve_config
from safeswitch.leftturn.render import render_scene
from safeswitch.leftturn.scenarios import named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.leftturn.vec_env import make_vec_env
from safeswitch.training.config import load_config


def _in_scenario(name: str, out: Path, controller: str) -> dict[str, Any]:
    """One paper scenario under the ``paper`` switching logic, driven by the rule-based system
    (``PID_th``) or by the shipped paper policy; a strip of frames is saved."""
    if controller == "rule":
        config = resolve_config({"episode": {"learned_scope": "never"}}, switching="paper")
        act: Any = None
    else:
        policy = load_policy("shipped")
        config = load_config(policy.path / "config.yaml").env
        act = policy.act
    task = LeftTurnTask(config)
    state = task.initial(named_scenarios(name, 1))
    frames: list[np.ndarray] = []
    safety, min_speed, cleared = 0, np.inf, None
    for tick in range(config.episode.horizon_ticks):
        action = np.zeros(1) if act is None else act(task.observe(state))
        state, record = task.step(state, action)
        safety += int(record.safety_active[0])
        min_speed = min(min_speed, float(record.ego_speed[0]))
        if cleared is None and record.ego_cleared[0]:
            cleared = (tick + 1) * config.episode.dt
        if tick % 75 == 74 and len(frames) < 6:
            frames.append(render_scene(task, state, 0, record))
    strip = np.concatenate(frames, axis=1)
    Image.fromarray(strip).save(out / f"{controller}_{name}.png")
    return {
        "scenario": name,
        "outcome": OUTCOMES[int(state.outcome[0])],
        "safety_ticks": safety,
        "min_speed_kmh": round(min_speed * 3.6, 2),
        "time_to_clear_s": cleared,
    }


def _full_throttle(switching: str, episodes: int) -> dict[str, Any]:
    config = LeftTurnConfig(switching=switching)  # type: ignore[arg-type]
    vec = make_vec_env(episodes, config=config, seed=2024)
    vec.reset()
    done = np.zeros(episodes, dtype=bool)
    collisions = np.zeros(episodes, dtype=bool)
    activated = np.zeros(episodes, dtype=bool)
    while not done.all():
        _, _, dones, infos = vec.step(np.ones((episodes, 1)))
        record = infos.record  # type: ignore[attr-defined]
        collisions |= record.collision & ~done
        activated |= record.safety_active & ~done
        done |= dones
    return {
        "switching": switching,
        "episodes": episodes,
        "collisions": int(collisions.sum()),
        "safety_activation_episodes": int(activated.sum()),
    }


def run_demo(out: str) -> int:
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    rule = [_in_scenario(name, path, "rule") for name in ("cut", "yield1", "yield2")]
    learned = [_in_scenario(name, path, "learned") for name in ("cut", "yield1", "yield2")]
    reckless = [_full_throttle(s, 1000) for s in ("none", "paper")]
    for title, rows in (
        ("Rule-based system (PID_th under the paper switching logic), paper scenarios:", rule),
        (
            "Shipped PPO policy (learned, under the paper switching logic), paper scenarios:",
            learned,
        ),
    ):
        print(title)
        print(f"  {'scenario':8} {'outcome':8} {'safety ticks':>12} {'min km/h':>9} {'clear s':>8}")
        for r in rows:
            clear = "never" if r["time_to_clear_s"] is None else f"{r['time_to_clear_s']:.2f}"
            print(
                f"  {r['scenario']:8} {r['outcome']:8} {r['safety_ticks']:>12} "
                f"{r['min_speed_kmh']:>9.1f} {clear:>8}"
            )
    print("A reckless learned controller (full throttle), 1,000 random scenarios:")
    for r in reckless:
        print(
            f"  switching={r['switching']:6} collisions={r['collisions']:4d}  "
            f"safety activated in {r['safety_activation_episodes']} episodes"
        )
    summary = {
        "rule_paper_scenarios": rule,
        "learned_paper_scenarios": learned,
        "full_throttle_random": reckless,
    }
    tmp = path / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    os.replace(tmp, path / "summary.json")
    print(f"Pictures and summary.json in {path}/")
    return 0
