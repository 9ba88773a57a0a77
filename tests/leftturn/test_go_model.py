"""The single-car scene's go predictor, ``episode.go_model`` (``traffic.go_model``'s are in
test_traffic.py)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.leftturn import make_vec_env
from safeswitch.leftturn.make import build_task
from safeswitch.training.config import comparable, dump_config, load_config, write_config_with_files

from .test_traffic import _write_go_model


def _by_hand(path, observation):
    m = np.load(path)
    h = np.tanh((observation.astype(np.float64) - m["mean"]) / m["std"] @ m["w0"] + m["b0"])
    return 1 / (1 + np.exp(-(h @ m["w1"] + m["b1"])[:, 0]))


@pytest.mark.parametrize("time_left", [False, True])
def test_the_go_model_ends_the_observation_with_its_probability(tmp_path, time_left):
    """The observation is the plain one (the paper's six values, then the time left if it is
    observed) and then the model's probability on it, within the space's bounds, on every
    step; the plant drives exactly as without it."""
    episode = {"observe_time_left": time_left, "learned_scope": "episode"}
    plain = build_task(None, {"episode": episode, "switching": "certified"})
    width = plain.observation_bounds[0].shape[0]
    assert width == 6 + time_left
    model = _write_go_model(tmp_path / "go.npz", width)
    task = build_task(None, {"episode": {**episode, "go_model": model}, "switching": "certified"})
    low, high = task.observation_bounds
    assert low.shape == (width + 1,) and (low[-1], high[-1]) == (0.0, 1.0)
    np.testing.assert_array_equal(low[:-1], plain.observation_bounds[0])
    scenes = task.scenario_set(11, 64)
    state, before = task.initial(scenes), plain.initial(scenes)
    probabilities = []
    for tick in range(60):
        obs, expected = task.observe(state), plain.observe(before)
        np.testing.assert_array_equal(obs[:, :-1], expected)
        np.testing.assert_allclose(obs[:, -1], _by_hand(model, expected), rtol=1e-4, atol=1e-5)
        assert ((obs >= low) & (obs <= high)).all()
        probabilities.append(obs[:, -1])
        action = np.full(64, 0.6 if tick % 2 else -0.2)
        state, record = task.step(state, action)
        before, _ = plain.step(before, action)
        np.testing.assert_array_equal(record.observation[:, :-1], plain.observe(before))
        np.testing.assert_array_equal(state.world.progress, before.world.progress)
    assert np.ptp(np.concatenate(probabilities)) > 0.01  # it reads the state, not a constant


def test_the_vec_env_and_its_space_carry_the_probability(tmp_path):
    model = _write_go_model(tmp_path / "go.npz", 6)
    env = make_vec_env(8, config={"episode": {"go_model": model}}, seed=3)
    observation = env.reset()
    assert env.observation_space.shape == (7,) and observation.shape == (8, 7)
    np.testing.assert_allclose(observation[:, -1], _by_hand(model, observation[:, :-1]),
                               rtol=1e-4, atol=1e-5)  # fmt: skip


def test_a_go_model_of_another_width_a_missing_one_or_one_in_traffic_is_refused(tmp_path):
    wrong = _write_go_model(tmp_path / "wide.npz", 7)
    with pytest.raises(ConfigError, match=r"episode\.go_model=.*wide\.npz.*width 7.*have 6"):
        build_task(None, {"episode": {"go_model": wrong}})
    np.savez(tmp_path / "other.npz", weights=np.zeros(3))
    with pytest.raises(ConfigError, match=r"episode\.go_model=.*other\.npz.*not a go model"):
        build_task(None, {"episode": {"go_model": str(tmp_path / "other.npz")}})
    with pytest.raises(ConfigError, match=r"go_model must be .*existing \.npz.*missing\.npz"):
        build_task(None, {"episode": {"go_model": str(tmp_path / "missing.npz")}})
    model = _write_go_model(tmp_path / "go.npz", 6)
    with pytest.raises(ConfigError, match=r"episode\.go_model=.*in traffic set traffic\.go_model"):
        build_task(None, {"episode": {"go_model": model}}, traffic="light")


def test_a_recipe_reads_its_go_model_beside_it_from_any_directory(tmp_path, monkeypatch):
    """``env.episode.go_model`` is a file setting, as ``traffic.go_model`` is: a relative path
    is read beside the configuration that names it."""
    (tmp_path / "models").mkdir()
    _write_go_model(tmp_path / "models" / "go.npz", 6)
    recipe = tmp_path / "models" / "recipe.yaml"
    recipe.write_text("base: certified\nenv:\n  episode:\n    go_model: go.npz\n")
    monkeypatch.chdir(tmp_path)
    go = load_config(recipe).env.episode.go_model
    assert go is not None and Path(go) == (tmp_path / "models" / "go.npz").resolve()
    # the recipe's other settings are the base's, untouched
    assert load_config(recipe).env.episode.decision_interval == 5


def test_a_folder_takes_the_files_its_config_names_and_refuses_another_of_that_name(tmp_path):
    """``write_config_with_files``: the go predictor is copied beside ``config.yaml``, which
    names it by its file name; a folder holding another file of that name is refused, naming
    it, with nothing written; and ``comparable`` tells the recipes apart by the file's
    contents, not its path."""
    (tmp_path / "a").mkdir()
    model = _write_go_model(tmp_path / "a" / "go.npz", 6)
    config = load_config("certified")
    config = replace(config, env=replace(config.env, episode=replace(config.env.episode,
                                                                     go_model=model)))  # fmt: skip
    folder = tmp_path / "run"
    folder.mkdir()
    write_config_with_files(folder, dump_config(config))
    assert (folder / "go.npz").read_bytes() == Path(model).read_bytes()
    assert "go_model: go.npz" in (folder / "config.yaml").read_text()
    assert (
        Path(load_config(folder / "config.yaml").env.episode.go_model)
        == (folder / "go.npz").resolve()
    )
    assert comparable(load_config(folder / "config.yaml")) == comparable(config)
    # another file of that name: refused, the folder as it was
    (tmp_path / "b").mkdir()
    other = _write_go_model(tmp_path / "b" / "go.npz", 6, seed=1)
    changed = replace(config, env=replace(config.env, episode=replace(config.env.episode,
                                                                      go_model=other)))  # fmt: skip
    assert comparable(changed) != comparable(config)
    before = (folder / "config.yaml").read_text()
    target = tmp_path / "second"
    target.mkdir()
    (target / "go.npz").write_bytes(Path(model).read_bytes())
    refused = r"env\.episode\.go_model=.*b/go\.npz.*holds another 'go\.npz'"
    with pytest.raises(ConfigError, match=refused):
        write_config_with_files(target, dump_config(changed))
    assert not (target / "config.yaml").exists()
    assert (folder / "config.yaml").read_text() == before


def test_the_probability_does_not_depend_on_how_many_blas_threads_the_process_allows():
    """The predictor is a policy input: on two BLAS threads OpenBLAS rounds its products
    differently (a run of the `certified` recipe differed from its first rollout), so it
    computes on one whatever the process allows, and a run is the same under any
    ``OPENBLAS_NUM_THREADS``."""
    import torch  # noqa: F401 -- loaded, as in training (its OpenMP changes how BLAS splits)
    from threadpoolctl import threadpool_limits

    task = build_task(None, load_config("certified").env)
    plain = task.observe(task.initial(task.scenario_set(0, 128)))[:, :6]
    with threadpool_limits(limits=1, user_api="blas"):
        one = task.go_model(plain)
    with threadpool_limits(limits=2, user_api="blas"):
        two = task.go_model(plain)
    np.testing.assert_array_equal(one, two)
