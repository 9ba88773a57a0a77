"""Where does the traffic policy, told the exact go check, lose time to the braked gap planner?
(issue #39; docs/learning_experiments.md, "Where the policy's own driving loses time").

"The exact go check in place of the predictor" left 0.004 of the oracle between the shipped
`traffic-certified` policy with the simulated go check in its observation (0.3797) and the gap
planner with the same check and a braked wait, deciding at the policy's rate (0.3837). This
one-off probe drives both on the same 1,000 `test` scenes of seed 1000003 under `certified` and
compares them scene by scene: in how many scenes each clears sooner and by how much, split by
whether each stood still before its first conflict zone (a wait) or drove through (a gap taken
on the way in). No training; the policy is unchanged.

Run: ``python experiments/probe_policy_vs_planner.py`` (one core, about 3 minutes).
"""

import numpy as np
from probe_exact_go_feature import MODEL, exact_go
from probe_go_rule import test_scenes
from probe_traffic_approach import BEST, RECIPE

from safeswitch.app.evaluate import controller_setup, fit_observations
from safeswitch.evaluation.evaluate import run_controller
from safeswitch.evaluation.oracle import efficiency
from safeswitch.evaluation.traffic_planner import GapPlanner


def times(task, driver, scenes, stood: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each scene's time to clear [s] (the horizon if never) and efficiency against the oracle
    (NaN where the oracle cannot clear, as the evaluation counts it), and (``stood``) whether
    the ego came to a stop before its first conflict zone."""
    entry = GapPlanner(task).first_entry
    stopped = np.zeros(len(scenes.arrival_offset), dtype=bool)

    def on_tick(state, record, tick):
        before = state.world.progress[:, 0] < entry
        stopped[:] |= before & (state.world.vehicles.speed[:, 0] < 0.1)

    result, plan = run_controller(task, driver, scenes, on_tick=on_tick, trace=False)
    if stood is not None:
        stood.append(stopped)
    horizon = task.config.episode.horizon_s
    cleared = np.where(np.isnan(result.time_to_clear), horizon, result.time_to_clear)
    return cleared, efficiency(plan.time_to_clear, result.time_to_clear, horizon)


def main() -> None:
    task, scenes = test_scenes(RECIPE)
    stood: list = []
    planner, planner_eff = times(task, GapPlanner(task, BEST), scenes, stood)
    task, scenes = test_scenes("traffic_certified")
    _, policy = controller_setup("learned", MODEL, "certified")
    policy = fit_observations(policy, MODEL, task)
    exact_go(task, "observed")
    learned, learned_eff = times(task, policy, scenes, stood)
    waited, policy_waited = stood
    counted = np.isfinite(planner_eff)
    gap = np.where(counted, learned_eff - planner_eff, 0.0)  # per scene, in efficiency
    print(f"efficiency: policy {np.nanmean(learned_eff):.4f}, planner "
          f"{np.nanmean(planner_eff):.4f} ({counted.sum()} scenes the oracle clears)")  # fmt: skip
    for label, rows in (
        ("all", np.ones_like(waited)), ("planner waited", waited),
        ("planner drove through, the policy too", ~waited & ~policy_waited),
        ("planner drove through, the policy stopped", ~waited & policy_waited),
        ("planner waited, the policy drove through", waited & ~policy_waited),
    ):  # fmt: skip
        d = learned[rows] - planner[rows]
        later = d[d > 0.1]
        median = np.median(later) if later.size else 0.0
        print(
            f"{label}: {rows.sum()} scenes; policy sooner by > 0.1 s in {(d < -0.1).sum()}, "
            f"later by > 0.1 s in {later.size} (median {median:.2f} s); "
            f"policy minus planner efficiency {gap[rows].sum() / counted.sum():+.4f}"
        )


if __name__ == "__main__":
    main()
