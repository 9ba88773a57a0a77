"""The policies that ship with the package: safe training, and the paper policy's quality on
scenarios it never saw (the issue targets)."""

import json

import pytest

from safeswitch.app.evaluate import controller_setup, evaluate
from safeswitch.evaluation.evaluate import run_controller, scenario_set
from safeswitch.evaluation.metrics import STOP_SPEED
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.training.config import load_config
from safeswitch.training.policies import SHIPPED_DIR, load_policy, resolve_model_dir
from safeswitch.training.shipped import MISSING_TARGETS

EVAL = {"scenarios": "random", "episodes": 1000, "seed": 424242, "out": None}
NAMES = ("paper", "paper_warm", "paper_scratch", "no_adas", "certified", "none")


def metrics(name):
    return json.loads((SHIPPED_DIR / name / "metrics.json").read_text())


@pytest.fixture(scope="module")
def paper():
    return evaluate("learned", "shipped", switching=None, **EVAL)


@pytest.fixture(scope="module")
def rule():
    return evaluate("rule", None, switching=None, **EVAL)


def test_every_shipped_policy_loads_with_its_config_and_acts_in_bounds():
    for name in NAMES:
        policy = load_policy(SHIPPED_DIR / name)
        config = load_config(SHIPPED_DIR / name / "config.yaml")
        # trained for as long as its config says (PPO rounds up to whole rollouts)
        rollout = config.ppo.n_steps * config.n_envs
        assert config.timesteps <= metrics(name)["timesteps"] < config.timesteps + rollout
        # a first observation of the policy's own task (`certified`: its go predictor's
        # probability last, read from the policy's folder)
        task = build_task(None, config.env)
        obs = task.observe(task.initial(task.scenario_set(0, 1)))
        assert obs.shape == (1, 7 if name == "certified" else 6)
        action = policy.act(obs)
        assert action.shape == (1,) and -1.0 <= action[0] <= 1.0
    assert resolve_model_dir("shipped") == SHIPPED_DIR / "paper"
    assert resolve_model_dir("paper-scratch") == SHIPPED_DIR / "paper_scratch"
    with pytest.raises(FileNotFoundError, match="no trained policy"):
        resolve_model_dir("nonexistent-run")


def test_training_with_a_safety_net_was_collision_free_and_without_one_was_not():
    """Under a certified logic (the `paper` policy trains under `guarded`) training cannot
    collide; under the paper logic alone, a heuristic on the friction plant, it rarely does;
    without a switch a third of the training episodes end in a collision."""
    for name in ("paper", "certified"):
        config = load_config(SHIPPED_DIR / name / "config.yaml")
        assert config.train_env.switching in ("guarded", "certified")
        assert metrics(name)["training"]["collisions"] == 0
    for name in ("paper_warm", "paper_scratch", "no_adas"):
        training = metrics(name)["training"]
        assert training["collisions"] <= 0.005 * training["episodes"]
    unswitched = metrics("none")["training"]
    assert unswitched["collisions"] > 0.2 * unswitched["episodes"]
    for name in NAMES:
        assert metrics(name)["timesteps"] >= 1_200_000
    # the warm-started policy's warm start (the planner and its clone driving) did not collide
    warm = metrics("paper_warm")["warm_start"]
    assert warm["collisions"] == 0 and warm["episodes"] >= 1000


def test_the_shipped_paper_policy_learned_from_a_random_start_without_demonstrations():
    """Issue #18: the `paper` policy is the paper's method — PPO with R_ADAS from a random
    initialisation — not a clone of our planner; it is deployed under the paper's logic."""
    config = load_config(SHIPPED_DIR / "paper" / "config.yaml")
    assert config.warm_start.episodes == 0 and metrics("paper")["warm_start"] is None
    assert config.env.adas_penalty and config.deployed_env.switching == "paper"
    assert metrics("paper")["deployed_switching"] == "paper"
    # Issue #39: its training guard assumes the scene's own north car (constant speed, at most
    # 32 km/h: tests/leftturn/test_certified.py shows it truthful); the environment it is
    # validated and evaluated in keeps the defaults, and its throttle is speed-limited.
    guard, deployed = config.train_env.certified, config.deployed_env.certified
    assert guard.other_max_accel < 0.1 and guard.other_max_speed_kmh < 33.0
    assert deployed.other_max_accel == 2.5 and deployed.other_max_speed_kmh == 50.0
    assert config.env.controllers.learned_speed_limiter_kmh == 29.9
    assert load_config(SHIPPED_DIR / "paper_warm" / "config.yaml").warm_start.episodes > 0


def test_paper_policy_is_safe_and_comfortable_on_unseen_scenarios(paper):
    assert paper["episodes"] == 1000
    assert paper["collisions"] == 0
    assert paper["safety_activation_episodes"] <= 0.02 * 1000
    assert paper["comfort_violation_fraction"] <= 0.005
    assert paper["stops"] <= 0.10 * 1000
    assert paper["cut_episodes"] >= 0.20 * 1000  # it cuts in front, and yields otherwise
    assert paper["yield_episodes"] >= 0.20 * 1000


@pytest.mark.slow
def test_the_ablation_needs_the_safety_controller_more_than_the_paper_policy(paper):
    ablation = evaluate("learned", "no-adas", switching=None, **EVAL)
    assert ablation["safety_activation_episodes"] > paper["safety_activation_episodes"]
    # and more than the paper's recipe from scratch, which the ablation differs from only by R_ADAS
    scratch = evaluate("learned", "paper-scratch", switching=None, **EVAL)
    assert ablation["safety_activation_episodes"] > scratch["safety_activation_episodes"]


def test_the_rule_baseline_is_safe_but_leans_on_the_safety_controller(rule, paper):
    assert rule["collisions"] == 0
    assert rule["safety_activation_episodes"] > 10 * max(paper["safety_activation_episodes"], 1)


def missing(folder):
    """A strict expected failure for a target the shipped policy in ``folder`` is known to
    miss on today's plant (``MISSING_TARGETS``): it fails the suite the day the policy meets
    it, so the mark is removed with the retraining (issue #39)."""
    why = MISSING_TARGETS.get(folder)
    return pytest.mark.xfail(why is not None, reason=why or "", strict=True)


def test_what_the_certified_policy_misses_is_said_with_its_own_evaluation():
    """The note every summary of the shipped `certified` policy carries quotes the figures
    its evaluation (1,000 unseen scenarios, seed 1000003, ``metrics.json``) measured."""
    e = metrics("certified")["evaluation"]
    assert (e["episodes"], e["seed"]) == (1000, 1000003)
    why = MISSING_TARGETS["certified"]
    assert f"clears {e['cleared_episodes']} of 1,000 scenarios at {e['mean_efficiency']:.3f}" in why
    assert f"needs the filter in {e['safety_activation_episodes']};" in why


@pytest.fixture(scope="module")
def certified():
    return evaluate("learned", "certified", switching=None, **EVAL)


def test_the_certified_policy_learned_from_a_random_start_and_never_fails_or_speeds(certified):
    """Issue #18's `certified` row, its safety half: trained from scratch (no demonstrations)
    under the certified logic, it never collides or loses control on the friction plant, and
    its throttle goes through the speed limiter: never above the tolerated 30 km/h."""
    config = load_config(SHIPPED_DIR / "certified" / "config.yaml")
    assert config.env.switching == "certified"
    assert config.warm_start.episodes == 0 and metrics("certified")["warm_start"] is None
    assert certified["collisions"] == 0 and certified["failures"] == 0
    assert config.env.controllers.learned_speed_limiter_kmh == 29.9
    assert certified["speeding_episodes"] == 0 and certified["max_speed_kmh"] <= 30.1


def test_the_certified_policy_has_learned_not_to_need_the_filter(certified):
    """The paper's point, kept under `certified`: trained with the filter's episodes as a
    constraint, the deterministic policy needs a safety action in at most 2 % of the unseen
    scenarios, keeps the comfort limits on all but 0.5 % of ticks and still cuts in front in a
    fifth of them."""
    assert certified["safety_activation_episodes"] <= 0.02 * EVAL["episodes"]
    assert certified["comfort_violation_fraction"] <= 0.005
    assert certified["cut_episodes"] >= 0.20 * EVAL["episodes"]


@pytest.fixture(scope="module")
def certified_on_the_issues_scenarios():
    """Issue #39 states its targets on the 1,000 unseen scenarios of seed 1000003 (what
    ``metrics.json``, the README and ``MISSING_TARGETS`` quote), not on the tests' own set."""
    return evaluate("learned", "certified", switching=None, **{**EVAL, "seed": 1_000_003})


def test_the_certified_policy_is_as_quick_as_the_target(certified_on_the_issues_scenarios):
    """Issue #39's `certified` row, its efficiency: 0.85 of the oracle or better (since the
    recipe's noise is annealed, 2026-12-06)."""
    assert certified_on_the_issues_scenarios["mean_efficiency"] >= 0.85


@missing("certified")
def test_the_certified_policy_clears_the_crossing(certified_on_the_issues_scenarios):
    """Issue #39's `certified` row: it clears the crossing in at least 99 % of the scenarios (an
    oracle under the filter's rules clears 997 of 1,000 with the recipe's zones, a careful
    driver 989: ``benchmarks/certified_ceiling.py``)."""
    assert certified_on_the_issues_scenarios["cleared_episodes"] >= 0.99 * EVAL["episodes"]


@missing("paper")
def test_the_paper_policy_keeps_the_speed_limit(paper):
    """A careful driver's rule the paper's reward only discourages: never above the tolerated
    30 km/h (with 0.1 km/h of rounding)."""
    assert paper["speeding_episodes"] == 0


# -- the paper's Section VI results, on the shipped policies ---------------------------------


def paper_scenarios(model):
    config, policy = controller_setup("learned", model, None)
    task = LeftTurnTask(config)
    batch, names = scenario_set(task, "paper", 3, 0)
    result, _ = run_controller(task, policy, batch)
    return {
        name: {
            "outcome": OUTCOMES[int(result.outcome[i])],
            "safety_steps": int(result.safety_steps[i]),
            "min_speed": float(result.min_speed[i]),
            "collision": bool(result.collision[i]),
        }
        for i, name in enumerate(names)
    }


@pytest.fixture(scope="module")
def paper_runs():
    return paper_scenarios("shipped")


def test_in_cut_the_paper_policy_passes_first_without_the_safety_controller(paper_runs):
    assert paper_runs["cut"]["outcome"] == "cut"
    assert paper_runs["cut"]["safety_steps"] == 0


def test_in_yield1_the_paper_policy_passes_second_without_stopping_or_safety(paper_runs):
    run = paper_runs["yield1"]
    assert run["outcome"] == "yield" and not run["collision"]
    assert run["safety_steps"] == 0
    assert run["min_speed"] > STOP_SPEED


def test_in_yield2_the_paper_policy_slows_further(paper_runs):
    assert paper_runs["yield2"]["outcome"] == "yield"
    assert paper_runs["yield2"]["min_speed"] < paper_runs["yield1"]["min_speed"]
    assert paper_runs["yield2"]["safety_steps"] == 0


def test_the_ablation_policy_triggers_the_safety_controller_in_a_yield_scenario():
    runs = paper_scenarios("no-adas")
    assert max(runs["yield1"]["safety_steps"], runs["yield2"]["safety_steps"]) > 0
    assert not any(run["collision"] for run in runs.values())


def test_the_paper_policy_is_within_85_percent_of_the_oracle(paper):
    assert paper["mean_efficiency"] >= 0.85


def test_the_paper_policy_clears_the_zone_no_later_than_the_rule_on_average(paper, rule):
    assert paper["mean_time_to_clear_s"] <= rule["mean_time_to_clear_s"]


# -- in traffic from every leg ------------------------------------------------------------------

TRAFFIC_EVAL = {**EVAL, "traffic": "test"}  # the denser, ruder family it was not trained on


@pytest.fixture(scope="module")
def traffic_runs():
    """The traffic-trained policies and the rule under each one's logic, on the same 1,000
    unseen scenes of the `test` family."""
    return {
        "certified": evaluate("learned", "traffic-certified", switching=None, **TRAFFIC_EVAL),
        "clone": evaluate("learned", "traffic-certified-clone", switching=None, **TRAFFIC_EVAL),
        "paper": evaluate("learned", "traffic-paper", switching=None, **TRAFFIC_EVAL),
        "rule_certified": evaluate("rule", None, switching="certified", **TRAFFIC_EVAL),
        "rule_paper": evaluate("rule", None, switching="paper", **TRAFFIC_EVAL),
    }


def test_the_certified_traffic_policy_learned_from_a_random_start_and_the_others_are_clones():
    """Issue #39's traffic row asks for PPO from a random start, no demonstrations: the shipped
    `traffic-certified` is (since 2026-12-05); the clone of the gap planner it replaced stays
    shipped as `traffic-certified-clone`, and `traffic-paper` is one too. Under the certified
    filter neither training nor the demonstrations collided."""
    for name in ("traffic_paper", "traffic_certified_clone", "traffic_certified"):
        config = load_config(SHIPPED_DIR / name / "config.yaml")
        assert config.traffic_settings is not None and config.traffic_settings.observe == "margins"
    for name in ("traffic_paper", "traffic_certified_clone"):
        config = load_config(SHIPPED_DIR / name / "config.yaml")
        assert config.warm_start.teacher == "gap_planner" and config.warm_start.episodes > 0
        assert config.warm_start.gap_planner.foresight == "observed"
    ours = load_config(SHIPPED_DIR / "traffic_certified" / "config.yaml")
    assert ours.warm_start.episodes == 0 and metrics("traffic_certified")["warm_start"] is None
    assert ours.refine.iterations == 0
    for name in ("traffic_certified", "traffic_certified_clone"):
        assert load_config(SHIPPED_DIR / name / "config.yaml").env.switching == "certified"
        assert metrics(name)["training"]["collisions"] == 0
    assert metrics("traffic_certified_clone")["warm_start"]["collisions"] == 0


@pytest.mark.slow
def test_the_certified_traffic_policy_never_collides_and_rarely_needs_the_filter(traffic_runs):
    """The issue's safety targets in traffic: no collision, the safety action in at most 5 %
    of the episodes, where the rule under the same filter leans on it in most of them."""
    ours, rule = traffic_runs["certified"], traffic_runs["rule_certified"]
    assert ours["episodes"] == 1000
    assert ours["collisions"] == 0 and ours["failures"] == 0
    assert ours["safety_activation_episodes"] <= 50
    assert rule["safety_activation_episodes"] > 500
    assert traffic_runs["clone"]["collisions"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("density", ["light", "medium", "heavy"])
def test_the_certified_traffic_policy_needs_the_filter_rarely_at_every_density(density):
    """Issue #39's traffic row: the safety action in at most 5 % of the episodes at every
    density, with no collision (the policy shipped before its larger go predictor needed it in
    4.4 % of the medium scenes, its recipe's seed 2 in 5.8 % of the light ones)."""
    ours = evaluate("learned", "traffic-certified", switching=None, **{**EVAL, "traffic": density})
    assert ours["episodes"] == 1000 and ours["failures"] == 0
    assert ours["safety_activation_episodes"] <= 50


@pytest.mark.slow
def test_the_certified_traffic_policy_clears_more_scenes_than_the_rule_and_the_clone(traffic_runs):
    """PPO from a random start clears more of the `test` scenes than the rule under the same
    filter and than the clone of the gap planner it replaced, as efficiently at least."""
    ours, rule, clone = (
        traffic_runs["certified"],
        traffic_runs["rule_certified"],
        traffic_runs["clone"],
    )
    assert ours["cleared_episodes"] > rule["cleared_episodes"]
    assert ours["cleared_episodes"] > clone["cleared_episodes"]
    assert ours["mean_efficiency"] >= clone["mean_efficiency"]
    # it keeps the speed limit (its throttle goes through the limiter)
    assert ours["speeding_episodes"] == 0


@pytest.mark.slow
@missing("traffic_certified")
def test_the_certified_traffic_policy_is_as_efficient_as_the_gap_planner(traffic_runs):
    """Issue #39's traffic row: at least the gap planner's efficiency on the `test` family, the
    planner under the same filter (the policy's narrower zones)."""
    config = load_config(SHIPPED_DIR / "traffic_certified" / "config.yaml")
    zones = config.env.certified
    planner = evaluate(
        "gap_planner", None, switching="certified", **TRAFFIC_EVAL,
        settings=(f"env.certified.ego_max_lateral_m={zones.ego_max_lateral_m}",
                  f"env.certified.zone_margin_m={zones.zone_margin_m}"),
    )  # fmt: skip
    assert planner["collisions"] == 0
    assert traffic_runs["certified"]["mean_efficiency"] >= planner["mean_efficiency"]


@pytest.mark.slow
def test_the_certified_traffic_policy_keeps_the_comfort_limits(traffic_runs):
    """A shipped policy keeps a careful driver's comfort limits as the left turn's rows count
    them (exceeded on at most 0.5 % of ticks), whether or not its row names them; the policy
    shipped before 2026-12-04 did not (0.57 % of the ticks)."""
    assert traffic_runs["certified"]["comfort_violation_fraction"] <= 0.005
    assert traffic_runs["clone"]["comfort_violation_fraction"] <= 0.005


@pytest.mark.slow
def test_the_paper_traffic_policy_collides_far_less_than_the_rule_under_that_logic(traffic_runs):
    """Under the paper logic (a heuristic) collisions stay possible in traffic; the policy that
    waits for the gaps the certified filter would accept has a fraction of the rule's."""
    ours, rule = traffic_runs["paper"], traffic_runs["rule_paper"]
    assert rule["collisions"] > 100
    assert ours["collisions"] <= rule["collisions"] / 10
    assert ours["safety_activation_episodes"] < rule["safety_activation_episodes"] / 5
