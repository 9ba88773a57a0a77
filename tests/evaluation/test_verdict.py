"""The verdict and the headline every summary leads with (issue #37): computed from the
summary's own counts, so a policy that speeds, fails or beats the oracle cannot pass for
good."""

import numpy as np

from safeswitch.app.sweep import table
from safeswitch.evaluation.evaluate import baseline_setup, run_controller, summary_against_oracle
from safeswitch.evaluation.verdict import headline, verdict
from safeswitch.leftturn.task import LeftTurnTask

GOOD = {
    "episodes": 1000, "failures": 0, "collisions": 0, "lost_control_episodes": 0,
    "safety_activation_episodes": 12, "comfort_violation_fraction": 0.003,
    "speeding_episodes": 0, "max_speed_kmh": 29.9, "mean_efficiency": 0.86,
    "faster_than_oracle_episodes": 0, "cleared_episodes": 995, "cut_episodes": 400,
    "yield_episodes": 595, "never_cleared_episodes": 5, "mean_time_to_clear_s": 7.1,
}  # fmt: skip


def marks(summary):
    return {c.name: c.ok for c in verdict(summary)}


def test_a_summary_within_every_target_passes_every_one():
    assert all(marks(GOOD).values())


def test_each_broken_rule_fails_its_own_target_and_no_other():
    cases = {
        "collisions": {"collisions": 1, "failures": 1},
        "failures": {"lost_control_episodes": 2, "failures": 2},
        "safety action": {"safety_activation_episodes": 21},
        "comfort": {"comfort_violation_fraction": 0.0051},
        "speed": {"speeding_episodes": 617, "max_speed_kmh": 38.6},
        "efficiency": {"mean_efficiency": 0.84},
        "cleared": {"cleared_episodes": 989, "yield_episodes": 589, "never_cleared_episodes": 11},
    }
    for target, change in cases.items():
        failed = {name for name, ok in marks({**GOOD, **change}).items() if ok is False}
        expected = {target} | ({"failures"} if target == "collisions" else set())
        assert failed == expected, (target, failed)


def test_an_efficiency_above_one_fails_and_says_which_limits_were_broken():
    summary = {**GOOD, "mean_efficiency": 1.176, "faster_than_oracle_episodes": 600,
               "faster_than_oracle_speeding": 590, "faster_than_oracle_comfort": 120,
               "faster_than_oracle_either": 595, "speeding_episodes": 892,
               "max_speed_kmh": 108.4}  # fmt: skip
    checks = {c.name: c for c in verdict(summary)}
    assert checks["efficiency"].ok is False and checks["speed"].ok is False
    assert "590 sped" in checks["efficiency"].value
    assert "5 neither" in checks["efficiency"].value
    lines = headline(summary)
    speeding = "✘ speeding: 892 episodes above 30 km/h (top 108.4"
    assert any(line.startswith(speeding) for line in lines)
    assert any("600 episodes cleared sooner than the oracle" in line for line in lines)


def test_the_headline_of_a_real_evaluation_adds_up():
    """cut + yield = cleared and failures = collisions + lost control, on a real summary."""
    config, policy = baseline_setup("rule")
    task = LeftTurnTask(config)
    scenarios = task.scenario_set(3, 300)
    result, plan = run_controller(task, policy, scenarios, trace=False)
    s = summary_against_oracle(result, plan, config.episode.horizon_s)
    assert s["cut_episodes"] + s["yield_episodes"] == s["cleared_episodes"]
    assert s["failures"] == s["collisions"] + s["lost_control_episodes"]
    last = headline(s)[-1]
    assert f"cleared {s['cleared_episodes']:,} = cut {s['cut_episodes']:,} + yield" in last
    assert s["faster_than_oracle_episodes"] >= s["faster_than_oracle_either"]
    assert np.isfinite(s["mean_efficiency"])


def test_the_sweep_table_shows_speeding_and_failures_beside_the_efficiency():
    run = {"metrics": {"training": {"failures": 0}, "evaluation": {**GOOD, "speeding_episodes": 889,
           "failures": 0, "faster_than_oracle_episodes": 40, "mean_efficiency": 0.961,
           "stops": 0}, "wall_time_s": 60}}  # fmt: skip
    text = table({"runs": {"fast": run}})
    header = text.splitlines()[0]
    for column in ("failures", "speeding", "top speed", "faster than the oracle", "efficiency"):
        assert column in header
    assert "✘ 889" in text and "✘ 40" in text and "0.961" in text
