import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import safeswitch
from safeswitch.core.config import ConfigError
from safeswitch.leftturn import LeftTurnEnv, make_vec_env
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.rewards import REWARD_TERMS

from .conftest import cruise_action

IMPLEMENTED = ("paper", "certified", "none")


@pytest.mark.parametrize("switching", IMPLEMENTED)
def test_gymnasium_and_sb3_env_checkers_pass(switching):
    env = gym.make(safeswitch.ENV_ID, switching=switching, render_mode="rgb_array")
    check_env(env.unwrapped)
    sb3_check_env(env.unwrapped)


def test_info_has_the_documented_fields():
    env = gym.make(safeswitch.ENV_ID, scenario="yield1")
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    for key in (
        "collision",
        "safety_active",
        "reward_terms",
        "reason",
        "learned_throttle",
        "safety_brake",
        "throttle",
        "brake",
        "controller",
    ):
        assert key in info
    assert set(info["reward_terms"]) == set(REWARD_TERMS)
    assert reward == pytest.approx(sum(info["reward_terms"].values()))


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"switching": "bogus"}, "bogus"),
        ({"scenario": "sideways"}, "sideways"),
        ({"config": {"episode": {"horizon_sec": 3}}}, "horizon_sec"),
        ({"config": {"paper": {"ttr_threshold_s": -1.0}}}, "ttr_threshold_s"),
        ({"config": {"vehicle": {"mass": -1.0}}}, "mass"),
        ({"config": {"episode": {"learned_scope": "always"}}}, "always"),
    ],
)
def test_invalid_configuration_names_the_bad_value(kwargs, named):
    with pytest.raises(ConfigError, match=named):
        LeftTurnEnv(**kwargs)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_nan_or_inf_action_never_reaches_the_plant_the_pedals_are_held(bad):
    env = LeftTurnEnv(scenario="cut", learned_scope="episode")
    env.reset(seed=0)
    for _ in range(30):
        env.step(np.array([0.4], dtype=np.float32))
    held = env.state.world.vehicles.throttle[0, 0], env.state.world.vehicles.brake[0, 0]
    obs, _, _, _, info = env.step(np.array([bad], dtype=np.float32))
    assert info["safety_active"] and info["reason"] == "invalid_learned_action"
    assert info["reward_terms"]["adas"] == -25.0  # an invalid action is penalised like a switch
    # the pedals stay where they were (far from the conflict, the paper logic accepts it)
    assert info["controller"] == "rule"
    assert (info["throttle"], info["brake"]) == held and held[0] > 0.6
    assert np.isfinite(obs).all()


def test_learned_scope_is_a_keyword_and_bad_actions_are_named():
    env = gym.make(safeswitch.ENV_ID, learned_scope="episode")
    assert env.unwrapped.config.episode.learned_scope == "episode"
    with pytest.raises(ConfigError, match="always"):
        gym.make(safeswitch.ENV_ID, learned_scope="always")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="the action is None"):
        env.step(None)
    with pytest.raises(ValueError, match="2 action value"):
        env.step(np.zeros(2, dtype=np.float32))
    *_, info = env.step(np.array([5.0], dtype=np.float32))
    assert info["action_clipped"] and info["learned_throttle"] == 3.0 and info["throttle"] == 1.0
    *_, info = env.step(np.array([0.5], dtype=np.float32))
    assert not info["action_clipped"]


def test_human_rendering_opens_a_window_or_says_why_not(monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "offscreen")  # a display pygame can always open
    env = LeftTurnEnv(render_mode="human")
    env.reset(seed=0)
    env.step(np.zeros(1, dtype=np.float32))
    assert env._window is not None and env._window.get_size() == (480, 480)
    env.close()
    monkeypatch.setenv("SDL_VIDEODRIVER", "no-such-driver")  # as on a machine without one
    env = LeftTurnEnv(render_mode="human")
    with pytest.raises(RuntimeError, match="needs a display and none can be opened here"):
        env.reset(seed=0)


def test_out_of_range_actions_are_clipped():
    outcomes = []
    for action in (1.0, 7.5):
        env = LeftTurnEnv(scenario="cut", config={"episode": {"learned_scope": "episode"}})
        env.reset(seed=0)
        for _ in range(20):
            obs, *_ = env.step(np.array([action], dtype=np.float32))
        outcomes.append(obs)
    np.testing.assert_array_equal(outcomes[0], outcomes[1])


def rollout_env(env, actions):
    observations, rewards = [], []
    for a in actions:
        obs, reward, terminated, truncated, _ = env.step(np.array([a], dtype=np.float32))
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            observations.append(env.reset()[0])
    return np.array(observations), np.array(rewards)


def test_same_seed_same_trajectory_in_the_env():
    actions = np.random.default_rng(0).uniform(-1, 1, 700)
    runs = []
    for _ in range(2):
        env = LeftTurnEnv(switching="paper")
        first, _ = env.reset(seed=42)
        obs, rewards = rollout_env(env, actions)
        runs.append((first, obs, rewards))
    for a, b in zip(runs[0], runs[1], strict=True):
        np.testing.assert_array_equal(a, b)
    other = LeftTurnEnv(switching="paper")
    assert not np.array_equal(other.reset(seed=43)[0], runs[0][0])


def test_vec_env_matches_single_envs_and_batch_size_does_not_matter():
    ticks = 200
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, (ticks, 8, 1)).astype(np.float32)
    big = make_vec_env(8, seed=5)
    big_obs = [big.reset()]
    big_rewards = []
    for t in range(ticks):
        obs, reward, _, _ = big.step(actions[t])
        big_obs.append(obs)
        big_rewards.append(reward)
    big_obs, big_rewards = np.array(big_obs), np.array(big_rewards)
    for i in (0, 3):
        env = LeftTurnEnv(env_index=i)
        first, _ = env.reset(seed=5)
        np.testing.assert_array_equal(first, big_obs[0, i])
        for t in range(ticks):
            obs, reward, *_ = env.step(actions[t, i])
            np.testing.assert_array_equal(obs, big_obs[t + 1, i])
            assert np.float32(reward) == big_rewards[t, i]
    small = make_vec_env(1, seed=5)
    obs = small.reset()
    for t in range(ticks):
        obs, *_ = small.step(actions[t, :1])
    np.testing.assert_array_equal(obs[0], big_obs[-1, 0])


def test_vec_env_auto_resets_like_sb3_expects():
    horizon = {"episode": {"horizon_s": 1.0}}  # 50 ticks
    vec = make_vec_env(3, seed=9, config=horizon)
    vec.reset()
    refs = [LeftTurnEnv(config=horizon, env_index=i) for i in range(3)]
    for env in refs:
        env.reset(seed=9)
    action = np.full((3, 1), 0.2)
    for tick in range(50):
        obs, _, dones, infos = vec.step(action)
        ref = [env.step(action[i].astype(np.float32)) for i, env in enumerate(refs)]
        if tick < 49:
            assert not dones.any()
            assert "terminal_observation" not in infos[0]
    assert dones.all()
    for i, env in enumerate(refs):
        last_obs, _, terminated, truncated, last_info = ref[i]
        assert truncated and not terminated
        np.testing.assert_array_equal(infos[i]["terminal_observation"], last_obs)
        # the last tick's own values, not those of the episode the reset put in its place
        for key in ("accel_lon", "accel_lat", "lateral_deviation", "ego_speed", "north_speed"):
            assert infos[i][key] == last_info[key], key
        assert infos[i]["TimeLimit.truncated"] is True
        assert infos[i]["episode"]["l"] == 50
        next_first, _ = env.reset()  # the second episode of environment i
        np.testing.assert_array_equal(obs[i], next_first)
        assert not np.array_equal(obs[i], last_obs)


def test_keyword_arguments_override_the_config_only_when_given():
    config = {"switching": "none", "scenario": "cut", "adas_penalty": False}
    assert make_vec_env(1, config=config).config.scenario == "cut"
    env = LeftTurnEnv(config=config, switching="paper")
    assert (env.config.switching, env.config.scenario, env.config.adas_penalty) == (
        "paper",
        "cut",
        False,
    )
    assert LeftTurnEnv().config.switching == "paper"
    # A nested section given as plain data replaces that section, validated like a config file.
    resolved = resolve_config(config, episode={"learned_scope": "episode"})
    assert (resolved.episode.learned_scope, resolved.scenario) == ("episode", "cut")
    assert resolved.episode.horizon_s == LeftTurnEnv().config.episode.horizon_s
    for bad, named in [
        ({"learned_scope": "always"}, "always"),
        ({"horizon_sec": 3}, "horizon_sec"),
    ]:
        with pytest.raises(ConfigError, match=named):
            resolve_config(config, episode=bad)


def test_a_collision_terminates_and_is_not_a_time_limit():
    vec = make_vec_env(
        1,
        switching="none",
        scenario="yield1",
        seed=0,
        config={"episode": {"learned_scope": "episode"}},
    )
    obs = vec.reset()
    for _ in range(600):  # cruise at the limit, unshielded, into a north car that has priority
        obs, _, dones, infos = vec.step(cruise_action(obs[:, 2])[:, None])
        if dones[0]:
            break
    assert dones[0] and infos[0]["collision"]
    assert infos[0]["TimeLimit.truncated"] is False
    assert infos[0]["episode"]["collision"]


def test_render_draws_both_cars():
    env = LeftTurnEnv(scenario="yield1", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(100):  # until both cars are in view
        env.step(np.array([0.0], dtype=np.float32))
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8
    colours = {tuple(c) for c in frame.reshape(-1, 3)}
    assert (40, 110, 230) in colours and (240, 150, 30) in colours  # ego blue, north orange


def test_lazy_infos_answer_bookkeeping_and_full_keys_alike():
    vec = make_vec_env(2, seed=1, config={"episode": {"horizon_s": 1.0}})  # 50 ticks
    vec.reset()
    _, _, _, infos = vec.step(np.zeros((2, 1)))
    assert infos[0].get("episode") is None and "terminal_observation" not in infos[0]
    assert infos[1]["collision"] is False and "reward_terms" in infos[1]
    for _ in range(49):
        _, _, dones, infos = vec.step(np.zeros((2, 1)))
    assert dones.all()
    assert infos[0]["episode"]["l"] == 50
    infos[0]["terminal_observation"] = "replaced"  # VecNormalize writes into infos
    assert infos[0]["terminal_observation"] == "replaced"
    assert set(dict(infos[1])) >= {"collision", "episode", "TimeLimit.truncated"}


def test_vec_env_follows_the_dummy_vec_env_contract():
    """reset_infos carry each episode's scenario (as the single Env reports it), get_attr and
    env_method act per environment, reset options are refused loudly."""
    vec = make_vec_env(3, seed=11, scenario=None)
    vec.reset()
    singles = [LeftTurnEnv(env_index=i) for i in range(3)]
    for i, env in enumerate(singles):
        assert vec.reset_infos[i]["scenario"] == env.reset(seed=11)[1]["scenario"]
    assert vec.env_method("scenario") == [info["scenario"] for info in vec.reset_infos]
    assert vec.env_method("episode_count", indices=[0, 2]) == [1, 1]
    assert vec.get_attr("env_index") == [0, 1, 2]
    assert vec.get_attr("config", indices=1) == [vec.config]
    with pytest.raises(AttributeError, match="environment 0 of the LeftTurnVecEnv has no"):
        vec.env_method("no_such_method", indices=0)
    with pytest.raises(ValueError, match="takes no reset options"):
        vec.set_options({"scenario": "cut"})
    vec.set_options(None)  # no options is fine
    # an auto-reset updates the ended environment's reset_info to its next scenario
    for _ in range(vec.config.episode.horizon_ticks):
        _, _, dones, infos = vec.step(np.zeros((3, 1), dtype=np.float32))
    assert dones.all()
    second = [env.reset()[1]["scenario"] for env in singles]
    assert [info["scenario"] for info in vec.reset_infos] == second
    # the infos behave like a list of dicts
    as_list = list(infos)
    assert len(as_list) == 3 and all(isinstance(i["reason"], str) for i in as_list)
    assert "terminal_observation" in infos[0] and infos[-1] is infos[2]


def test_a_decision_holds_the_action_for_decision_interval_ticks():
    """With decision_interval 5 one step is 5 ticks of the same action: the same trajectory
    and summed reward as five 1-tick steps; the VecEnv agrees with the Env; episodes still
    end on the tick they end."""
    base = {"episode": {"learned_scope": "episode"}}
    fine = LeftTurnEnv(config=base, switching="none")
    held = {"episode": {"learned_scope": "episode", "decision_interval": 5}}
    coarse = LeftTurnEnv(config=held, switching="none")
    fine.reset(seed=4)
    coarse.reset(seed=4)
    actions = np.random.default_rng(0).uniform(-1, 1, 200)
    for a in actions:
        total, done = 0.0, False
        for _ in range(5):
            obs_f, r, term_f, trunc_f, _ = fine.step(np.array([a], dtype=np.float32))
            total += r
            if term_f or trunc_f:
                done = True
                break
        obs_c, reward, term_c, trunc_c, _ = coarse.step(np.array([a], dtype=np.float32))
        np.testing.assert_array_equal(obs_c, obs_f)
        assert reward == pytest.approx(total) and (term_c, trunc_c) == (term_f, trunc_f)
        if done:
            break
    assert done and (term_c or trunc_c)  # the episode's end was reached, on the same tick
    held = {"episode": {"learned_scope": "episode", "decision_interval": 5}}
    vec = make_vec_env(1, seed=4, switching="none", config=held)
    vec.reset()
    coarse.reset(seed=4)
    for a in actions[:30]:
        obs_v, reward_v, _, _ = vec.step(np.array([[a]], dtype=np.float32))
        obs_c, reward_c, *_ = coarse.step(np.array([a], dtype=np.float32))
        np.testing.assert_array_equal(obs_v[0], obs_c)
        assert reward_v[0] == pytest.approx(reward_c, rel=1e-6)


def test_rollouts_ask_the_policy_once_per_decision():
    from safeswitch.evaluation.rollout import rollout
    from safeswitch.leftturn.task import LeftTurnTask

    task = LeftTurnTask(resolve_config({"episode": {"decision_interval": 4}}))
    asked = []

    def policy(obs, state, tick):
        asked.append(tick)
        return np.zeros(obs.shape[0])

    rollout(task, task.draw_scenarios(0, np.arange(3), np.zeros(3, int)), policy)
    assert asked == list(range(0, task.config.episode.horizon_ticks, 4))


@pytest.mark.parametrize("traffic", [None, {"preset": "light", "observed": 2, "horizon_s": 2.0}])
def test_the_time_left_is_the_last_observed_value_when_asked_for(traffic):
    """``episode.observe_time_left`` appends the seconds left to the horizon, after the scene's
    values (the traffic's too), within the observation space; the scene's values are those of
    the same episode without it; the terminal observation holds 0 s left at the horizon."""
    episode = {"horizon_s": 2.0, "decision_interval": 5, "learned_scope": "episode"}
    timed = make_vec_env(3, seed=2, traffic=traffic, config={"episode": {
        **episode, "observe_time_left": True}})  # fmt: skip
    plain = make_vec_env(3, seed=2, traffic=traffic, config={"episode": episode})
    width = plain.observation_space.shape[0]
    assert timed.observation_space.shape == (width + 1,)
    assert timed.observation_space.high[-1] == 2.0 and timed.observation_space.low[-1] == 0.0
    obs, ref = timed.reset(), plain.reset()
    np.testing.assert_array_equal(obs[:, :width], ref)
    np.testing.assert_array_equal(obs[:, -1], 2.0)
    action = np.full((3, 1), 0.3, dtype=np.float32)
    for step in range(1, 20):
        obs, _, dones, _ = timed.step(action)
        ref, *_ = plain.step(action)
        np.testing.assert_array_equal(obs[:, :width], ref)
        assert all(timed.observation_space.contains(o) for o in obs) and not dones.any()
        np.testing.assert_allclose(obs[:, -1], 2.0 - 0.1 * step, atol=1e-5)  # 0.1 s a step
    obs, _, dones, infos = timed.step(action)  # the 20th decision: the horizon
    assert dones.all() and all(infos[i]["TimeLimit.truncated"] for i in range(3))
    assert [infos[i]["terminal_observation"][-1] for i in range(3)] == [0.0] * 3
    np.testing.assert_array_equal(obs[:, -1], 2.0)  # the fresh episodes'


def test_the_horizon_terminates_only_when_asked_for_and_with_the_clock():
    """``episode.horizon_terminates`` turns the horizon's truncation into a termination (no
    ``TimeLimit.truncated``: nothing is bootstrapped after it) and changes nothing before it;
    without the time left in the observation it is refused, naming the key."""
    episode = {"horizon_s": 2.0, "decision_interval": 5, "learned_scope": "episode",
               "observe_time_left": True}  # fmt: skip
    ends = make_vec_env(3, seed=2, config={"episode": {**episode, "horizon_terminates": True}})
    cuts = make_vec_env(3, seed=2, config={"episode": episode})
    np.testing.assert_array_equal(ends.reset(), cuts.reset())
    action = np.full((3, 1), 0.3, dtype=np.float32)
    for _ in range(20):
        obs, reward, dones, infos = ends.step(action)
        ref, ref_reward, ref_dones, ref_infos = cuts.step(action)
        np.testing.assert_array_equal(obs, ref)
        np.testing.assert_array_equal(reward, ref_reward)
        np.testing.assert_array_equal(dones, ref_dones)
    assert dones.all()  # the 20th decision is the horizon
    assert [i["TimeLimit.truncated"] for i in ref_infos] == [True] * 3
    assert [i["TimeLimit.truncated"] for i in infos] == [False] * 3
    assert ends.last_record.terminated.all() and not ends.last_record.truncated.any()
    assert not ends.last_record.collision.any()
    env = LeftTurnEnv(config={"episode": {**episode, "horizon_terminates": True}})
    env.reset(seed=3)
    for _ in range(19):
        _, _, terminated, truncated, _ = env.step(np.array([0.3], dtype=np.float32))
        assert not (terminated or truncated)
    _, _, terminated, truncated, info = env.step(np.array([0.3], dtype=np.float32))
    assert terminated and not truncated and not info["collision"]
    with pytest.raises(ConfigError, match=r"episode\.horizon_terminates .*observe_time_left"):
        resolve_config({"episode": {"horizon_terminates": True}})
