"""Potential-based progress shaping: what PPO sees, and what it leaves alone."""

import numpy as np
import pytest

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.config import EnvTrainConfig, ShapingConfig, TrainConfig
from safeswitch.training.shaping import (
    ClearTimePenalty,
    CounterfactualPenalty,
    PenaltySchedule,
    ProgressShaping,
    ReasonPenalty,
    ShapingSchedule,
)

GAMMA, K = 0.99, 2.0


def make(n=6):
    config = {"episode": {"horizon_s": 2.0, "decision_interval": 5, "learned_scope": "episode"}}
    base = LeftTurnVecEnv(n, config=config, seed=4)
    return base, ProgressShaping(base, K, GAMMA)


def test_the_shaping_telescopes_over_each_episode_and_the_paper_reward_is_untouched():
    """Per episode, the discounted sum of the shaping terms is ``γ^T·Φ(last) − Φ(first)``:
    the potential of the episode that ended, not of the one that follows; the environment's
    own reward and its episode return are the paper's."""
    base, env = make()
    env.reset()
    rng = np.random.default_rng(0)
    start = K * base.state.world.progress[:, 0].copy()
    discounted, paper, power = np.zeros(6), np.zeros(6), np.ones(6)
    checked = 0
    for _ in range(40):
        env.step_async(rng.uniform(-1, 1, (6, 1)))
        _, reward, done, infos = env.step_wait()
        paper += paper_reward(base)
        discounted += power * (reward - paper_reward(base))
        power *= GAMMA
        for i in np.flatnonzero(done):
            last = K * base.ego_progress_after_step[i]
            assert discounted[i] == pytest.approx(power[i] * last - start[i], abs=1e-3)
            assert infos[i]["episode"]["r"] == pytest.approx(paper[i], rel=1e-5)
            start[i] = K * base.state.world.progress[i, 0]
            discounted[i], paper[i], power[i] = 0.0, 0.0, 1.0
            checked += 1
    assert checked >= 12


def test_a_collision_is_an_absorbing_state_whose_potential_is_zero():
    """Where an episode terminates in a collision (nothing is bootstrapped after it) the
    shaping sums to ``−Φ(first)``: a collision earns nothing for the metres the ego came;
    episodes that go on keep their potential."""
    config = {"episode": {"decision_interval": 5, "learned_scope": "episode"}}
    base = LeftTurnVecEnv(32, config=config, seed=4, switching="none")  # nothing stops it
    env = ProgressShaping(base, K, GAMMA)
    env.reset()
    start = K * base.state.world.progress[:, 0].copy()
    discounted, power = np.zeros(32), np.ones(32)
    collided = 0
    for _ in range(130):
        env.step_async(np.ones((32, 1)))  # full throttle into whatever comes
        _, reward, done, _ = env.step_wait()
        discounted += power * (reward - paper_reward(base))
        power *= GAMMA
        for i in np.flatnonzero(done):
            terminal = base.last_record.terminated[i]
            last = 0.0 if terminal else K * base.ego_progress_after_step[i]
            assert discounted[i] == pytest.approx(power[i] * last - start[i], abs=1e-3)
            collided += int(terminal)
            start[i] = K * base.state.world.progress[i, 0]
            discounted[i], power[i] = 0.0, 1.0
    assert collided >= 5


def paper_reward(base):
    """The paper's reward of the last step, as the environment itself returns it."""
    return base.last_record.reward.astype(np.float32)


def test_the_ego_moving_on_pays_and_standing_still_costs_only_the_discount():
    base, env = make(2)
    env.reset()
    env.step_async(np.array([[1.0], [-1.0]]))  # full throttle; closed throttle from a roll
    before = K * base.state.world.progress[:, 0].copy()
    _, reward, _, _ = env.step_wait()
    shaped = reward - paper_reward(base)
    after = K * base.ego_progress_after_step
    np.testing.assert_allclose(shaped, GAMMA * after - before, atol=1e-4)
    assert shaped[0] > shaped[1]


def test_bad_shaping_settings_are_named():
    with pytest.raises(ConfigError, match="progress_shaping"):
        ShapingConfig(progress_shaping=-1.0)
    with pytest.raises(ConfigError, match=r"ppo\.'progress_shaping'"):  # the left turn's only
        from_dict(EnvTrainConfig, {"env_id": "CartPole-v1", "ppo": {"progress_shaping": 1.0}})
    with pytest.raises(TypeError, match="LeftTurnVecEnv"):
        ProgressShaping(object(), 1.0, 0.99)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"progress_shaping_final .*needs progress_shaping"):
        ShapingConfig(progress_shaping_final=1.0)
    with pytest.raises(ConfigError, match=r"progress_shaping_final .*-2\.0"):
        ShapingConfig(progress_shaping=5.0, progress_shaping_final=-2.0)


def test_an_annealed_shaping_falls_linearly_over_the_run_and_shapes_with_its_current_k():
    """``shaping.progress_shaping_final``: before each rollout ``k`` is set from the run's
    progress; the next step's shaping uses it."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    base, env = make(2)
    schedule = ShapingSchedule(env, start=K, final=0.5)
    model = SimpleNamespace(
        get_env=lambda: env, logger=configure(None, []), _current_progress_remaining=1.0
    )
    schedule.init_callback(model)  # type: ignore[arg-type]
    seen = []
    for remaining in (1.0, 0.75, 0.5, 0.0):
        model._current_progress_remaining = remaining
        schedule.on_rollout_start()
        seen.append(env.per_metre)
    np.testing.assert_allclose(seen, [K, K - 0.375, K - 0.75, 0.5])
    env.reset()
    env.step_async(np.array([[1.0], [1.0]]))
    before = base.state.world.progress[:, 0].copy()
    _, reward, _, _ = env.step_wait()
    expected = 0.5 * (GAMMA * base.ego_progress_after_step - before)
    np.testing.assert_allclose(reward - paper_reward(base), expected, atol=1e-4)
    with pytest.raises(ValueError, match="final=-1"):
        ShapingSchedule(env, start=K, final=-1.0)


def test_the_reasons_that_acted_are_counted_per_tick_and_charged_as_configured():
    """``shaping.reason_penalties``: with a decision per tick, a step's counts are exactly the
    reason its ``info`` reports when the safety action ran; the penalty PPO sees is those
    counts times the configured values, and the environment's own reward is unchanged."""
    config = {"episode": {"decision_interval": 1, "learned_scope": "episode"}}
    base = LeftTurnVecEnv(32, config=config, seed=7, switching="guarded")
    penalties = {"guard:backup_stop": -50.0, "no_gap_at_braking_point": -1.0}
    env = ReasonPenalty(base, penalties)
    assert base.count_reasons
    env.reset()
    rng = np.random.default_rng(1)
    seen = dict.fromkeys(penalties, 0)
    for step in range(700):
        if step % 10 == 0:  # bang-bang throttle: both logics get work to do
            action = rng.choice([-1.0, 1.0], (32, 1))
        env.step_async(action)
        _, reward, _, infos = env.step_wait()
        counts = base.reason_ticks_in_step
        for i, info in enumerate(infos):
            expected = np.zeros(len(base.task.reasons), np.int32)
            if info["safety_active"]:
                expected[base.task.reasons.index(info["reason"])] = 1
            np.testing.assert_array_equal(counts[i], expected)
        charged = sum(v * counts[:, base.task.reasons.index(k)] for k, v in penalties.items())
        np.testing.assert_allclose(reward - paper_reward(base), charged, atol=1e-3)
        for name in penalties:
            seen[name] += int(counts[:, base.task.reasons.index(name)].sum())
    assert min(seen.values()) > 0, seen  # both reasons acted and were charged


def test_ramped_reason_penalties_charge_their_share_of_the_configured_values():
    """``shaping.reason_penalties_initial_scale``: before each rollout the charge is scaled
    linearly from the initial share to the full value; each step charges counts × values ×
    the current scale."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    config = {"episode": {"decision_interval": 1, "learned_scope": "episode"}}
    base = LeftTurnVecEnv(32, config=config, seed=7, switching="guarded")
    penalties = {"guard:backup_stop": -50.0, "no_gap_at_braking_point": -1.0}
    env = ReasonPenalty(base, penalties)
    schedule = PenaltySchedule(env, start=0.2)
    model = SimpleNamespace(
        get_env=lambda: env, logger=configure(None, []), _current_progress_remaining=1.0
    )
    schedule.init_callback(model)  # type: ignore[arg-type]
    env.reset()
    rng = np.random.default_rng(1)
    charged_ticks = 0
    for remaining, expected_scale in ((1.0, 0.2), (0.5, 0.6), (0.0, 1.0)):
        model._current_progress_remaining = remaining
        schedule.on_rollout_start()
        assert env.scale == pytest.approx(expected_scale)
        for step in range(250):
            if step % 10 == 0:
                action = rng.choice([-1.0, 1.0], (32, 1))
            env.step_async(action)
            _, reward, _, _ = env.step_wait()
            counts = base.reason_ticks_in_step
            full = sum(v * counts[:, base.task.reasons.index(k)] for k, v in penalties.items())
            np.testing.assert_allclose(
                reward - paper_reward(base), expected_scale * full, atol=1e-3
            )
            charged_ticks += int((full != 0).sum())
    assert charged_ticks > 0
    with pytest.raises(ValueError, match=r"start=-0\.5"):
        PenaltySchedule(env, start=-0.5)


def test_the_clear_time_penalty_charges_each_step_until_the_ego_clears_or_the_horizon():
    """``shaping.clear_time_penalty``: per episode, the cost is ``c`` per second for every step
    begun with the ego short of its zone's exit — as many steps as the environment's own
    time to clear spans — and a collision before the exit pays the whole horizon."""
    per_second, interval, horizon = 10.0, 5, 6.0
    config = {"episode": {"decision_interval": interval, "learned_scope": "episode",
                          "horizon_s": horizon}}  # fmt: skip
    base = LeftTurnVecEnv(48, config=config, seed=3, switching="none")
    env = ClearTimePenalty(base, per_second)
    env.reset()
    rng = np.random.default_rng(2)
    step_s = interval * base.config.episode.dt
    action = rng.uniform(-1, 1, (48, 1))  # one throttle per episode: some crawl, some collide
    total = np.zeros(48)
    kinds = {"cleared": 0, "collided": 0, "never": 0}
    for _ in range(400):
        env.step_async(action)
        _, reward, done, infos = env.step_wait()
        total += paper_reward(base) - reward
        for i in np.flatnonzero(done):
            summary = infos[i]["episode"]
            if summary["collision"] and np.isnan(summary["time_to_clear"]):
                expected, kind = per_second * horizon, "collided"
            elif np.isnan(summary["time_to_clear"]):
                expected, kind = per_second * horizon, "never"
            else:
                ticks = round(summary["time_to_clear"] / base.config.episode.dt)
                expected, kind = per_second * step_s * -(-ticks // interval), "cleared"
            assert total[i] == pytest.approx(expected, abs=1e-2), (kind, summary)
            kinds[kind] += 1
            total[i] = 0.0
            action[i] = rng.uniform(-1, 1)
    assert min(kinds.values()) > 0, kinds  # every case was met
    with pytest.raises(ValueError, match="per_second=-1"):
        ClearTimePenalty(base, -1.0)
    with pytest.raises(ConfigError, match=r"clear_time_penalty .*-5"):
        ShapingConfig(clear_time_penalty=-5.0)


def test_bad_reason_penalties_are_named():
    base = LeftTurnVecEnv(2, seed=1, switching="paper")
    with pytest.raises(ValueError, match=r"\['guard:backup_clear'\] not reasons of .*'paper'"):
        ReasonPenalty(base, {"guard:backup_clear": -50.0})
    with pytest.raises(ValueError, match="finite and <= 0"):
        ReasonPenalty(base, {"no_gap_at_braking_point": 5.0})
    with pytest.raises(ConfigError, match=r"reason_penalties\['x'\] .*got 3"):
        ShapingConfig(reason_penalties={"x": 3})
    with pytest.raises(ConfigError, match="reason_penalties"):
        ShapingConfig(reason_penalties={"x": "a lot"})
    with pytest.raises(ConfigError, match=r"reason_penalties_initial_scale .*1\.5"):
        ShapingConfig(reason_penalties={"x": -1.0}, reason_penalties_initial_scale=1.5)
    with pytest.raises(ConfigError, match=r"reason_penalties_initial_scale .*needs reason_pen"):
        ShapingConfig(reason_penalties_initial_scale=0.0)


def _episodes_hit(env, vec, actions, episodes, hit):
    """``{(environment, episode)}`` on whose steps ``hit()`` held (after each step), with
    ``actions`` held in every environment for its first ``episodes`` episodes; and the
    rewards of every step."""
    env.reset()
    count = np.zeros(vec.num_envs, int)
    hits, rewards = set(), []
    while count.min() < episodes:
        env.step_async(actions)
        _, reward, done, _ = env.step_wait()
        live = count < episodes
        hits |= {(i, count[i]) for i in np.flatnonzero(hit() & live)}
        rewards.append(np.where(live, reward, 0.0))
        count += done
    return hits, np.array(rewards)


BAND = {  # where the paper logic's gap lies
    "episode": {"learned_scope": "episode", "decision_interval": 5},
    "scenarios": {"arrival_offset_s": [1.0, 3.5]},
}


@pytest.mark.slow
def test_the_first_counterfactual_of_an_episode_is_the_episode_under_the_deployed_logic_alone():
    """``shaping.counterfactual_penalty``: with a constant action per environment the guarded and
    the paper-alone episodes are the same until the guard first intervenes, so the
    counterfactual rolled from there is the paper-alone episode: the episodes whose first
    counterfactual collides are exactly those that collide under ``paper`` alone (on the same
    scenarios). The real episodes never collide, and the reward PPO sees differs from the
    guarded one by the penalty on exactly the steps whose counterfactual collided."""
    n, episodes, penalty = 64, 3, -1000.0
    actions = np.linspace(-0.6, 1.0, n)[:, None]

    def make(switching):
        return LeftTurnVecEnv(n, switching=switching, seed=11, config=BAND)

    paper = make("paper")
    collided, _ = _episodes_hit(
        paper, paper, actions, episodes, lambda: paper.last_record.collision
    )
    plain = make("guarded")
    real, plain_rewards = _episodes_hit(
        plain, plain, actions, episodes, lambda: plain.last_record.collision
    )
    env = CounterfactualPenalty(make("guarded"), penalty, 30.0, "paper")
    env.reset()
    count = np.zeros(n, int)
    first: dict[tuple[int, int], bool] = {}  # (environment, episode) -> first one collided
    for plain_reward in plain_rewards:
        env.step_async(actions)
        _, reward, done, _ = env.step_wait()
        live = count < episodes
        for i in np.flatnonzero(env.rolled & live):
            first.setdefault((i, count[i]), bool(env.collided[i]))
        extra = np.where(live, reward - plain_reward, 0.0)
        np.testing.assert_allclose(extra, np.where(live & env.collided, penalty, 0.0), atol=1e-3)
        count += done
    assert len(collided) >= 2  # the comparison has collisions in it
    assert {key for key, hit in first.items() if hit} == collided
    assert not real
    assert env.collisions >= len(collided) and env.rollouts > env.collisions


def test_a_short_counterfactual_horizon_misses_collisions_beyond_it():
    """The rollout stops at its horizon: rolled for 0.1 s only, it cannot see a collision
    that the paper logic's braking brings about later."""
    actions = np.linspace(-0.6, 1.0, 64)[:, None]
    vec = LeftTurnVecEnv(64, switching="guarded", seed=11, config=BAND)
    env = CounterfactualPenalty(vec, -1000.0, 0.1, "paper")
    charged, _ = _episodes_hit(env, vec, actions, 3, lambda: env.collided)
    assert not charged and env.rollouts > 0


def test_bad_counterfactual_settings_are_named():
    guarded = LeftTurnVecEnv(2, seed=1, switching="guarded")
    with pytest.raises(ValueError, match=r"penalty=5\.0"):
        CounterfactualPenalty(guarded, 5.0, 4.0, "paper")
    with pytest.raises(ValueError, match=r"horizon_s=nan"):
        CounterfactualPenalty(guarded, -1.0, float("nan"), "paper")
    with pytest.raises(ValueError, match=r"'paper' has no 'guard:' reasons"):
        CounterfactualPenalty(LeftTurnVecEnv(2, seed=1, switching="paper"), -1.0, 4.0, "paper")
    with pytest.raises(TypeError, match="single-car left turn"):
        CounterfactualPenalty(
            LeftTurnVecEnv(2, seed=1, switching="guarded", traffic="light"), -1.0, 4.0, "paper"
        )
    with pytest.raises(ConfigError, match=r"counterfactual_penalty .*got 3"):
        ShapingConfig(counterfactual_penalty=3)
    with pytest.raises(ConfigError, match=r"counterfactual_horizon_s .*got 0"):
        ShapingConfig(counterfactual_horizon_s=0)
    with pytest.raises(ConfigError, match="needs deploy_switching"):
        TrainConfig(
            shaping=ShapingConfig(counterfactual_penalty=-1.0), env={"switching": "guarded"}
        )
