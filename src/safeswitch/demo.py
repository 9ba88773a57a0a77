"""``safeswitch demo``: the framework on the embedded simulator, end to end, printed.

Until training and evaluation land, the demo shows the two halves of the paper's claim that do
not need a trained policy: the rule-based system (``PID_th`` under the paper's switching logic)
in the three Section VI scenarios, and a reckless learned controller (full throttle) over 1,000
random scenarios with and without the switching logic.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from safeswitch.leftturn.config import LeftTurnConfig, resolve_config
from safeswitch.leftturn.render import render_scene
from safeswitch.leftturn.scenarios import named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.leftturn.vec_env import make_vec_env


def _rule_in_scenario(name: str, out: Path) -> dict[str, Any]:
    config = resolve_config({"episode": {"learned_scope": "never"}}, switching="paper")
    task = LeftTurnTask(config)
    state = task.initial(named_scenarios(name, 1))
    frames: list[np.ndarray] = []
    safety, min_speed, cleared = 0, np.inf, None
    for tick in range(config.episode.horizon_ticks):
        state, record = task.step(state, np.zeros(1))
        safety += int(record.safety_active[0])
        min_speed = min(min_speed, float(record.ego_speed[0]))
        if cleared is None and record.ego_cleared[0]:
            cleared = (tick + 1) * config.episode.dt
        if tick % 75 == 74 and len(frames) < 6:
            frames.append(render_scene(task, state, 0, record))
    strip = np.concatenate(frames, axis=1)
    Image.fromarray(strip).save(out / f"rule_{name}.png")
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
    rule = [_rule_in_scenario(name, path) for name in ("cut", "yield1", "yield2")]
    reckless = [_full_throttle(s, 1000) for s in ("none", "paper")]
    print("Rule-based system (PID_th under the paper switching logic), paper scenarios:")
    print(f"  {'scenario':8} {'outcome':8} {'safety ticks':>12} {'min km/h':>9} {'clear s':>8}")
    for r in rule:
        print(
            f"  {r['scenario']:8} {r['outcome']:8} {r['safety_ticks']:>12} "
            f"{r['min_speed_kmh']:>9.1f} {r['time_to_clear_s']:>8.2f}"
        )
    print("A reckless learned controller (full throttle), 1,000 random scenarios:")
    for r in reckless:
        print(
            f"  switching={r['switching']:6} collisions={r['collisions']:4d}  "
            f"safety activated in {r['safety_activation_episodes']} episodes"
        )
    summary = {"rule_paper_scenarios": rule, "full_throttle_random": reckless}
    tmp = path / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    os.replace(tmp, path / "summary.json")
    print(f"Pictures and summary.json in {path}/")
    return 0
