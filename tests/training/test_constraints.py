"""Constrained PPO: the multipliers' update, the costs charged per tick, what is measured, and
the staggered episode starts it relies on."""

import csv
import json

import numpy as np
import pytest

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training import train
from safeswitch.training.config import ConstraintConfig, ConstraintsConfig, TrainConfig
from safeswitch.training.constraints import ConstraintCosts, Multiplier

FIXED = {"integral_gain": 0.0}  # a multiplier that stays at its initial value


def test_the_multiplier_follows_the_proportional_integral_update_by_hand():
    """``e = clip(measured / budget − 1, −1, 4)``; ``I ← clip(I + ki·e, 0, max)``;
    ``λ ← clip(kp·e + I, 0, max)`` — recomputed by hand for a sequence of rollouts."""
    m = Multiplier(budget=0.01, integral_gain=2.0, proportional_gain=1.0, maximum=10.0)
    # measured:   3x budget (e=2), nothing (e=-1), on budget (e=0), 100x (e clipped to 4)
    values = [m.update(x) for x in (0.03, 0.0, 0.01, 1.0)]
    # integral:   0+4=4           4-2=2           2             2+8=10 (at the maximum)
    # value:      1*2+4=6         -1+2=1          0+2=2         4+10=14 -> 10
    assert values == pytest.approx([6.0, 1.0, 2.0, 10.0])
    assert m.integral == pytest.approx(10.0)
    floor = Multiplier(budget=1.0, integral_gain=1.0, proportional_gain=3.0, maximum=5.0)
    assert floor.update(0.0) == 0.0  # never negative: kp·e + I = -3 + 0
    assert floor.integral == 0.0


def make(n, switching="guarded", horizon_s=4.0, interval=1, **constraints):
    config = {"episode": {"decision_interval": interval, "learned_scope": "episode",
                          "horizon_s": horizon_s}}  # fmt: skip
    base = LeftTurnVecEnv(n, config=config, seed=7, switching=switching)
    settings = ConstraintsConfig(**{k: ConstraintConfig(**v) for k, v in constraints.items()})
    return base, ConstraintCosts(base, settings, min_episodes=1)


def test_each_cost_is_counted_per_tick_charged_at_its_multiplier_and_measured_per_episode():
    """With a decision per tick the costs of a step are what its ``info`` reports — a tick over
    a comfort limit, the episode's first such tick, a tick over the tolerated speed, the
    episode's first safety action, the ego not yet clear, an episode that ends uncleared — and
    PPO's reward is the paper's minus
    each cost times its multiplier. What the wrapper measures over the ended episodes equals
    the episode summaries the environment itself reports."""
    base, env = make(
        24,
        horizon_s=8.0,
        comfort={"budget": 0.01, "initial_multiplier": 3.0, **FIXED},
        comfort_episodes={"budget": 0.1, "initial_multiplier": 11.0, **FIXED},
        speeding={"budget": 0.01, "initial_multiplier": 2.0, **FIXED},
        safety={"budget": 0.01, "initial_multiplier": 20.0, **FIXED},
        clear_time={"budget": 3.0, "initial_multiplier": 0.5, **FIXED},
        uncleared={"budget": 0.1, "initial_multiplier": 7.0, **FIXED},
    )
    limits = base.config.rewards
    env.reset()
    rng = np.random.default_rng(1)
    episodes, seen, uncomfortable = [], np.zeros(24, dtype=bool), np.zeros(24, dtype=bool)
    for step in range(600):
        if step % 10 == 0:  # bang-bang throttle: comfort breaks, both logics act, some speed
            action = rng.choice([-1.0, 1.0], (24, 1), p=[0.3, 0.7])
        env.step_async(action)
        _, reward, done, infos = env.step_wait()
        paper = base.last_record.reward
        lon, lat = limits.comfort_accel_lon, limits.comfort_accel_lat
        comfort = np.array([abs(i["accel_lon"]) > lon or abs(i["accel_lat"]) > lat for i in infos])
        fast = np.array([i["ego_speed"] > 30.1 / 3.6 for i in infos])  # R_v's best + 0.1 km/h
        safety = np.array([i["safety_active"] for i in infos])
        first_safety = safety & ~seen
        seen |= safety
        first_comfort = comfort & ~uncomfortable
        uncomfortable |= comfort
        uncleared = ~base.last_record.ego_cleared
        ended_uncleared = done & uncleared
        expected = paper - 3.0 * comfort - 2.0 * fast - 20.0 * first_safety - 0.5 * uncleared
        expected -= 7.0 * ended_uncleared + 11.0 * first_comfort
        np.testing.assert_allclose(reward, expected, atol=1e-3)
        episodes += [infos[int(i)]["episode"] for i in np.flatnonzero(done)]
        seen[done] = uncomfortable[done] = False
    measured = env.measured()
    ticks = sum(e["l"] for e in episodes)
    assert measured["comfort"] == pytest.approx(
        sum(e["comfort_violation_steps"] for e in episodes) / ticks
    )
    assert measured["speeding"] == pytest.approx(sum(e["speeding_steps"] for e in episodes) / ticks)
    assert all(
        (e["speeding_steps"] > 0) == (e["max_speed"] > 30.1 / 3.6) for e in episodes
    )  # the episode summary's two speeding figures agree
    with_comfort = sum(e["comfort_violation_steps"] > 0 for e in episodes)
    assert measured["comfort_episodes"] == pytest.approx(with_comfort / len(episodes))
    assert measured["comfort_episodes"] > 2 * measured["comfort"]  # episodes, not ticks
    with_safety = sum(e["safety_steps"] > 0 for e in episodes)
    assert measured["safety"] == pytest.approx(with_safety / len(episodes))
    # the time to clear: the tick on which the ego cleared (it is not charged), or the horizon
    horizon = base.config.episode.horizon_s
    times = [
        horizon if np.isnan(e["time_to_clear"]) else e["time_to_clear"] - 0.02 for e in episodes
    ]
    assert measured["clear_time"] == pytest.approx(np.mean(times))
    never = [np.isnan(e["time_to_clear"]) for e in episodes]
    assert measured["uncleared"] == pytest.approx(np.mean(never)) and 0 < np.mean(never) < 1
    assert measured["comfort"] > 0 and measured["safety"] > 0  # the costs were there to charge
    assert 0 < sum(e["speeding_steps"] > 0 for e in episodes) < len(episodes)
    assert min(times) < horizon  # and some egos cleared


def test_a_collision_is_charged_the_rest_of_the_horizon_in_clear_time():
    """Ending an episode in a collision never saves clear-time cost: an ego that collides
    before it clears pays the whole horizon."""
    base, env = make(32, switching="none", horizon_s=6.0, interval=5,
                     clear_time={"budget": 3.0, "initial_multiplier": 1.0, **FIXED})  # fmt: skip
    env.reset()
    total = np.zeros(32)
    collided = 0
    for _ in range(70):
        env.step_async(np.ones((32, 1)))  # full throttle, nothing stops it
        _, reward, done, _ = env.step_wait()
        total += base.last_record.reward - reward
        for i in np.flatnonzero(done):
            if base.last_record.terminated[i] and not base.last_record.ego_cleared[i]:
                assert total[i] == pytest.approx(300.0)  # 6 s of 50 Hz ticks at 1 per tick
                collided += 1
            total[i] = 0.0
    assert collided >= 3


def test_the_multipliers_move_only_once_enough_episodes_ended_and_after_their_start():
    _, env = make(
        8, horizon_s=1.0,
        clear_time={"budget": 0.1, "integral_gain": 1.0, "start": 0},
        comfort={"budget": 1e-6, "integral_gain": 1.0, "start": 10_000},
    )  # fmt: skip
    env.min_episodes = 8
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(10):  # 10 ticks: no episode of 50 ticks has ended
        env.step_async(rng.uniform(-1, 1, (8, 1)))
        env.step_wait()
    assert env.end_rollout(timesteps=0) is None
    assert env.multipliers["clear_time"].value == 0.0
    for _ in range(45):
        env.step_async(np.ones((8, 1)))
        env.step_wait()
    measured = env.end_rollout(timesteps=0)
    assert measured is not None and measured["clear_time"] > 0.1
    assert env.multipliers["clear_time"].value == pytest.approx(4.0)  # far over its budget
    assert env.multipliers["comfort"].value == 0.0  # its start is not reached


def test_staggered_starts_cut_each_first_episode_at_a_random_tick_and_nothing_else():
    """``stagger``: every environment's first episode is truncated (a time limit: SB3
    bootstraps it) at a tick drawn from the seed; later episodes run the whole horizon and
    play the same scenarios as without staggering."""
    config = {"episode": {"decision_interval": 5, "learned_scope": "episode", "horizon_s": 2.0}}
    ends = {}
    for stagger in (False, True):
        vec = LeftTurnVecEnv(16, config=config, seed=5, stagger=stagger)
        vec.reset()
        lengths, scenarios = [[] for _ in range(16)], [[] for _ in range(16)]
        for _ in range(50):
            vec.step_async(np.zeros((16, 1)))
            _, _, done, infos = vec.step_wait()
            for i in np.flatnonzero(done):
                assert infos[int(i)]["TimeLimit.truncated"]
                lengths[i].append(infos[int(i)]["episode"]["l"])
                scenarios[i].append(vec.reset_infos[i]["scenario"])
        ends[stagger] = (lengths, scenarios)
    plain, staggered = ends[False][0], ends[True][0]
    assert all(set(run) == {100} for run in plain)  # in step: every episode the horizon
    firsts = [run[0] for run in staggered]
    assert len(set(firsts)) > 8 and all(5 <= f <= 100 for f in firsts)  # spread, in range
    assert all(set(run[1:]) == {100} for run in staggered)
    for with_, without in zip(ends[True][1], ends[False][1], strict=True):
        assert with_[: len(without)][:3] == without[:3]  # the same scenarios, in order
    again = LeftTurnVecEnv(16, config=config, seed=5, stagger=True)
    again.reset()
    np.testing.assert_array_equal(
        again._stagger_cuts(),
        LeftTurnVecEnv(16, config=config, seed=5, stagger=True)._stagger_cuts(),
    )


SMALL = {
    "timesteps": 8192,
    "n_envs": 8,
    "seed": 3,
    "checkpoint_every": 2048,
    "eval_episodes": 20,
    "torch_threads": 1,
    "stagger_starts": True,
    "constraints": {
        "clear_time": {"budget": 0.5, "integral_gain": 0.1},  # the ego cannot clear in 2 s
        "comfort": {"budget": 0.001, "integral_gain": 0.5, "start": 6000},
    },
    "env": {"episode": {"learned_scope": "episode", "horizon_s": 2.0, "decision_interval": 5}},
}


@pytest.mark.slow
def test_a_constrained_run_records_its_multipliers_and_resumes_them(tmp_path, interrupted_training):
    """The multipliers are part of a checkpoint: a resumed run starts from the values the
    interrupted one had, and ``metrics.json`` holds the final ones."""
    config = from_dict(TrainConfig, SMALL)
    run = tmp_path / "run"
    interrupted_training(config, run, at=4096)
    checkpoints = sorted((run / "checkpoints").glob("step_*"))
    saved = json.loads((checkpoints[-1] / "state.json").read_text())["constraints"]
    assert saved["clear_time"]["value"] > 0 and saved["comfort"]["value"] == 0  # by their starts
    resumed = []
    original = ConstraintCosts.restore

    def spy(self, state):
        original(self, state)
        resumed.append({k: m.value for k, m in self.multipliers.items()})

    ConstraintCosts.restore = spy  # type: ignore[method-assign]
    try:
        metrics = train(config, run, resume=True, progress_bar=False)
    finally:
        ConstraintCosts.restore = original  # type: ignore[method-assign]
    assert resumed == [{k: v["value"] for k, v in saved.items()}]
    assert set(metrics["constraints"]) == {"comfort", "clear_time"}
    assert metrics["constraints"]["clear_time"]["value"] > saved["clear_time"]["value"]
    with open(run / "constraints.csv", newline="") as handle:  # one row per update, resumed
        rows = list(csv.DictReader(handle))
    steps = [int(r["timesteps"]) for r in rows]
    assert steps == sorted(set(steps)) and steps[-1] == metrics["timesteps"]
    multipliers = [float(r["clear_time_multiplier"]) for r in rows]
    assert multipliers == sorted(multipliers)  # the ego never clears: it only rises
    assert multipliers[-1] == pytest.approx(metrics["constraints"]["clear_time"]["value"])
    assert {float(r["comfort_multiplier"]) for r in rows if int(r["timesteps"]) < 6000} == {0.0}


def test_bad_constraint_settings_are_named():
    with pytest.raises(ConfigError, match=r"budget .*-0\.1"):
        ConstraintConfig(budget=-0.1)
    with pytest.raises(ConfigError, match=r"initial_multiplier .*50"):
        ConstraintConfig(budget=0.1, initial_multiplier=50.0, max_multiplier=10.0)
    with pytest.raises(ConfigError, match=r"constraints\.comfort\.reasons"):
        ConstraintsConfig(comfort=ConstraintConfig(budget=0.1, reasons=("learned",)))
    with pytest.raises(ConfigError, match=r"constraints\.safety\.budget .*is a share"):
        ConstraintsConfig(safety=ConstraintConfig(budget=2.0))
    with pytest.raises(ConfigError, match=r"clear_time\.budget .*horizon \(12\.0 s\)"):
        from_dict(TrainConfig, {"constraints": {"clear_time": {"budget": 12.0}}})
    # in traffic the traffic's horizon (30 s for the presets) is the episode's
    in_traffic = {"traffic": "train", "constraints": {"clear_time": {"budget": 20.0}}}
    assert from_dict(TrainConfig, in_traffic).constraints.clear_time.budget == 20.0
    with pytest.raises(ConfigError, match=r"clear_time\.budget .*horizon \(20\.0 s\)"):
        from_dict(TrainConfig, {**in_traffic, "traffic": {"preset": "train", "horizon_s": 20}})
    with pytest.raises(
        ConfigError, match=r"unknown configuration key constraints\.comfort\.'budgt'"
    ):
        from_dict(TrainConfig, {"constraints": {"comfort": {"budgt": 0.1}}})
    with pytest.raises(ConfigError, match=r"criterion .*needs constraints"):
        from_dict(
            TrainConfig, {"validation": {"every": 100, "criterion": "constraints_then_return"}}
        )
    with pytest.raises(ValueError, match=r"\['no_gap'\] not reasons .*no_gap_at_braking_point"):
        make(2, safety={"budget": 0.1, "reasons": ("no_gap",)})


def test_the_overrule_cost_counts_the_filter_overruling_the_paper_logics_braking():
    """``overrule`` (under ``guarded``): by default every ``…:overrules_primary`` reason; each
    step's cost is exactly the ticks on which one of them acted."""
    base, env = make(32, overrule={"budget": 0.01, "initial_multiplier": 1.0, **FIXED})
    overrules = [k for k, r in enumerate(base.task.reasons) if r.endswith(":overrules_primary")]
    assert len(overrules) == 5  # every reason of the certified filter but 'learned'
    env.reset()
    rng = np.random.default_rng(3)
    charged = 0
    for step in range(700):
        if step % 10 == 0:
            action = rng.choice([-1.0, 1.0], (32, 1))
        env.step_async(action)
        _, reward, _, infos = env.step_wait()
        acted = np.array([i["safety_active"] and i["reason"].endswith(":overrules_primary")
                          for i in infos])  # fmt: skip
        np.testing.assert_allclose(base.last_record.reward - reward, acted, atol=1e-4)
        charged += int(acted.sum())
    assert charged > 0
    with pytest.raises(ValueError, match=r"'paper' has no ':overrules_primary' reasons"):
        make(2, switching="paper", overrule={"budget": 0.01})


def test_a_policy_is_evaluated_and_validated_under_the_logic_it_is_deployed_under(tmp_path):
    """``deploy_switching``: trained under ``guarded``, the run's own evaluation, its
    validation and ``safeswitch evaluate --model`` run it under ``paper``."""
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.training.validation import Validator

    config = from_dict(TrainConfig, SMALL | {
        "timesteps": 2048, "deploy_switching": "paper", "validation": {"every": 1024},
        "env": {**SMALL["env"], "switching": "guarded"},
    })  # fmt: skip
    assert Validator(config, tmp_path / "v").task.config.switching == "paper"
    run = tmp_path / "run"
    metrics = train(config, run, progress_bar=False)
    assert (metrics["switching"], metrics["deployed_switching"]) == ("guarded", "paper")
    assert controller_setup("learned", str(run), None)[0].switching == "paper"
    assert controller_setup("learned", str(run), "certified")[0].switching == "certified"
    with pytest.raises(ConfigError, match=r"deploy_switching .*'papr'"):
        from_dict(TrainConfig, {"deploy_switching": "papr"})


def _twins(make, cost, multiplier, seed):
    """Two copies of the same two environments, one with ``cost`` constrained at
    ``multiplier``: what the constraint changes is the difference between them."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from safeswitch.training.config import ConstraintConfig
    from safeswitch.training.constraints import NamedCostConstraints

    plain, charged = DummyVecEnv([make] * 2), DummyVecEnv([make] * 2)
    plain.seed(seed)
    charged.seed(seed)
    wrapped = NamedCostConstraints(charged, {cost: ConstraintConfig(budget=0.1)}, 1)
    wrapped.multipliers[cost].value = multiplier
    plain.reset()
    wrapped.reset()
    return plain, wrapped


def test_a_plants_named_cost_is_charged_at_its_multiplier_and_measured_per_step():
    import gymnasium as gym

    from tests.core import user_plant

    plain, wrapped = _twins(lambda: gym.make(user_plant.ENV_ID), "speeding", 3.0, seed=3)
    fast = np.full((2, 1), 2.0, dtype=np.float32)
    total, steps, first = np.zeros(2), np.zeros(2), np.ones(2, dtype=bool)
    while first.any():  # full acceleration: faster than 5 m/s soon, into the wall in the end
        _, r0, done, infos = plain.step(fast)
        _, r1, _, _ = wrapped.step(fast)
        cost = np.array([info["costs"]["speeding"] for info in infos])
        assert np.allclose(r1, r0 - 3.0 * cost)
        total += np.where(first, cost, 0.0)  # each environment's first episode
        steps += first
        first &= ~done
    measured = wrapped.end_rollout(timesteps=10**9)
    rate = total.sum() / steps.sum()
    assert measured is not None and measured["speeding"] == pytest.approx(rate)
    assert rate > 0.1 and wrapped.multipliers["speeding"].value > 3.0  # over budget: it rose


def test_the_switchs_intervention_rate_is_a_constraint_on_any_plant():
    import gymnasium as gym

    from safeswitch.core.wrappers import SafeSwitch
    from tests.core import user_plant

    def make():
        env = gym.make(user_plant.ENV_ID)
        return SafeSwitch(env, user_plant.full_brake, user_plant.LOGIC, penalty=0.0)

    plain, wrapped = _twins(make, "intervention", 2.0, seed=5)
    ran = 0
    for _ in range(70):  # full acceleration toward the wall: the logic steps in
        fast = np.full((2, 1), 2.0, dtype=np.float32)
        _, r0, _, infos = plain.step(fast)
        _, r1, _, _ = wrapped.step(fast)
        cost = np.array([info["cost"] for info in infos])
        assert (cost == [float(info["safety_active"]) for info in infos]).all()
        assert np.allclose(r1, r0 - 2.0 * cost)
        ran += int(cost.sum())
    assert ran > 0
    measured = wrapped.end_rollout(timesteps=10**9)
    assert measured is not None and 0 < measured["intervention"] <= 1
