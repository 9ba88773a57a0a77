"""SUMO as a second simulator (issue #15): its network is our intersection, the task on SUMO
behaves as on the embedded simulator, the certified logic stays collision-free, and worker
processes end with their parent."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("libsumo")
sumolib = pytest.importorskip("sumolib")

import gymnasium as gym  # noqa: E402

import safeswitch  # noqa: E402
from safeswitch.evaluation.adversaries import catalogue, constant  # noqa: E402
from safeswitch.evaluation.rollout import rollout  # noqa: E402
from safeswitch.leftturn.config import ConfigError  # noqa: E402
from safeswitch.leftturn.make import build_task  # noqa: E402
from safeswitch.leftturn.scenarios import named_scenarios  # noqa: E402
from safeswitch.leftturn.task import LeftTurnTask  # noqa: E402
from safeswitch.sim.params import IntersectionGeometry  # noqa: E402
from safeswitch.sumo import network  # noqa: E402
from safeswitch.sumo.task import (  # noqa: E402
    LeftTurnSumoTrafficTask,
    make_sumo_vec_env,
    sumo_task,
)
from safeswitch.training.policies import load_policy  # noqa: E402


@pytest.fixture
def task():
    t = sumo_task({"episode": {"learned_scope": "episode"}})
    yield t
    t.close()


def test_the_network_is_our_intersection():
    g = IntersectionGeometry()
    net = sumolib.net.readNet(str(network.network_file(g)))
    lane = net.getEdge("south_in").getLanes()[0]
    (x0, y0), (x1, y1) = lane.getShape()
    assert (x0, x1) == (g.lane_width / 2, g.lane_width / 2)
    assert y0 == -(g.box_half_size + g.approach_length) and y1 == -g.box_half_size
    assert lane.getWidth() == g.lane_width
    xs = [x for x, _ in net.getNode("centre").getShape()]
    assert min(xs) == -g.box_half_size and max(xs) == g.box_half_size
    # the main road has the right of way
    assert net.getEdge("north_in").getPriority() > net.getEdge("east_in").getPriority()


@pytest.mark.parametrize("name", ["cut", "yield1", "yield2"])
def test_the_paper_policy_does_on_sumo_what_it_does_on_ours(task, name):
    """Same outcome, no collision, time to clear within a tick or two and safety ticks within
    a handful: SUMO's north car holds its speed as our autopilot does."""
    policy = load_policy("shipped").as_policy()
    embedded = LeftTurnTask(task.config)
    scenario = named_scenarios(name, 1)
    on_sumo = rollout(task, scenario, policy)
    on_ours = rollout(embedded, scenario, policy)
    assert not on_sumo.collision[0] and task.sumo_collisions == 0
    assert on_sumo.outcome[0] == on_ours.outcome[0]
    assert abs(on_sumo.time_to_clear[0] - on_ours.time_to_clear[0]) <= 0.1
    assert abs(int(on_sumo.safety_steps[0]) - int(on_ours.safety_steps[0])) <= 15
    assert not task.assumption_breaks


@pytest.mark.slow
def test_certified_never_collides_on_sumo():
    """Adversaries drive whole episodes of random scenarios on SUMO under the certified
    logic: no collision, by our check or SUMO's."""
    task = sumo_task({"episode": {"learned_scope": "episode"}}, switching="certified")
    try:
        collisions = sumo_reported = breaks = 0
        for k in range(12):
            scenario = task.draw_scenarios(41, np.array([k]), np.zeros(1, dtype=np.int64))
            for name in ("uniform", "full_throttle", "enter_then_stop", "creep", "nan_inf"):
                result = rollout(task, scenario, catalogue(task, 1, k)[name]())
                collisions += int(result.collision[0])
                sumo_reported += task.sumo_collisions
                breaks += int(task.assumption_breaks)
        assert (collisions, sumo_reported, breaks) == (0, 0, 0)
    finally:
        task.close()


@pytest.mark.slow
def test_sumos_collisions_are_ours_within_a_tick():
    """SUMO's own collision check against ours, computed on SUMO's poses of its car: a
    constant throttle without a switching logic into the north car (slow enough that the
    ego's tyres hold). Every collision SUMO reports is one where our footprints came within
    0.5 m (a tick of both cars' motion at these speeds), and SUMO reports some of ours. It
    misses many (its check works on its lanes and sees the ego moved a step late): a coarse
    cross-check only — the figures count ours (README, "SUMO")."""
    task = sumo_task({"episode": {"learned_scope": "episode"}}, switching="none")
    try:
        seen = []
        for k in range(40):
            scenario = task.draw_scenarios(3, np.array([k]), np.zeros(1, dtype=np.int64))
            slid = [False]

            def watch(state, record, tick, slid=slid):
                slid[0] |= bool(record.grip_demand[0] > 1.0)

            result = rollout(task, scenario, constant(0.0), watch)
            assert not slid[0]
            seen.append((bool(result.collision[0]), task.sumo_collisions > 0,
                         float(result.min_separation[0])))  # fmt: skip
        assert sum(ours for ours, _, _ in seen) >= 5
        assert any(ours and theirs for ours, theirs, _ in seen), seen
        assert all(gap <= 0.5 for _, theirs, gap in seen if theirs), seen
    finally:
        task.close()


def test_the_gym_environment_runs_an_episode():
    env = gym.make(safeswitch.SUMO_ENV_ID, switching="certified", learned_scope="episode")
    try:
        obs, _ = env.reset(seed=3)
        assert env.observation_space.contains(obs)
        done, info = False, {}
        while not done:
            obs, _, terminated, truncated, info = env.step(np.array([0.5], dtype=np.float32))
            done = terminated or truncated
        assert info["sumo_collisions"] == 0 and "assumption_breaks" in info
    finally:
        env.close()


def test_what_sumo_cannot_do_is_refused_by_name(task):
    with pytest.raises(ConfigError, match="rush-hour"):
        sumo_task(None, traffic="rush-hour")
    with pytest.raises(ValueError, match="batch of 4"):
        task.initial(task.draw_scenarios(0, np.arange(4), np.zeros(4, dtype=np.int64)))


def test_a_north_car_starting_inside_the_junction_is_placed_there(task):
    """SUMO inserts vehicles on approaches only; the north car is inserted earlier and driven
    to where the scenario starts it."""
    scenario = task.draw_scenarios(41, np.array([3]), np.zeros(1, dtype=np.int64))
    scenario.arrival_offset[:] = -3.0
    state = task.initial(scenario)
    ours = LeftTurnTask(task.config).initial(scenario)
    assert ours.world.progress[0, 1] > task.config.geometry.approach_length - 2.45
    assert abs(state.world.progress[0, 1] - ours.world.progress[0, 1]) < 0.3


def test_a_second_simulation_in_one_process_is_refused(task):
    task.initial(named_scenarios("cut", 1))
    other = sumo_task(None)
    with pytest.raises(RuntimeError, match="one SUMO simulation per process"):
        other.initial(named_scenarios("cut", 1))
    task.close()  # then it may run
    other.initial(named_scenarios("cut", 1))
    other.close()


def test_missing_sumo_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "sumo", None)
    with pytest.raises(network.SumoMissingError, match=r"safeswitch\[sumo\]"):
        network.sumo_home()


@pytest.mark.slow
def test_vec_env_workers_step_and_close():
    env = make_sumo_vec_env(2, seed=5, learned_scope="episode")
    try:
        obs = env.reset()
        assert obs.shape == (2, 6)
        for _ in range(20):
            obs, reward, _, _ = env.step(np.full((2, 1), 0.3, dtype=np.float32))
        assert np.isfinite(reward).all()
        pids = [p.pid for p in env.processes]
    finally:
        env.close()
    time.sleep(0.5)
    assert not any(_alive(pid) for pid in pids)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as handle:  # a zombie is gone for our purposes
        return handle.read().split()[2] != "Z"


@pytest.mark.slow
@pytest.mark.parametrize("how", ["interrupt", "kill"])
def test_no_worker_outlives_a_dying_parent(how):
    """The parent is interrupted (Ctrl-C) or killed outright mid-run: its SUMO workers end."""
    script = textwrap.dedent(
        """
        import signal, sys, time
        import numpy as np
        # as in a terminal: a shell that started the tests in the background (`cmd &`) leaves
        # SIGINT ignored, which the child would inherit
        signal.signal(signal.SIGINT, signal.default_int_handler)
        from safeswitch.sumo.task import make_sumo_vec_env
        env = make_sumo_vec_env(2, seed=1)
        env.reset()
        print(" ".join(str(p.pid) for p in env.processes), flush=True)
        while True:
            env.step(np.zeros((2, 1), dtype=np.float32))
        """
    )
    child = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True,
    )  # fmt: skip
    try:
        pids = [int(p) for p in child.stdout.readline().split()]
        assert len(pids) == 2
        time.sleep(1.0)
        child.send_signal(signal.SIGINT if how == "interrupt" else signal.SIGKILL)
        child.wait(timeout=30)
        deadline = time.time() + 30
        while time.time() < deadline and any(_alive(pid) for pid in pids):
            time.sleep(0.2)
        assert not any(_alive(pid) for pid in pids)
    finally:
        if child.poll() is None:
            child.kill()


# -- traffic from every leg on SUMO ----------------------------------------------------------

EPISODE = {"episode": {"learned_scope": "episode"}}


def _scene(task, k):
    return task.draw_scenarios(11, np.array([k]), np.zeros(1, dtype=np.int64))


def test_sumo_starts_the_embedded_traffic_scene():
    """The same vehicles on the same routes where the embedded scene has them, at their
    speeds; the north car and the ego as in the paper's scene."""
    task = sumo_task(EPISODE, traffic="heavy", switching="certified")
    ours = build_task(None, EPISODE, traffic="heavy", switching="certified")
    assert isinstance(task, LeftTurnSumoTrafficTask)
    try:
        for k in range(4):
            on_sumo, embedded = task.initial(_scene(task, k)), ours.initial(_scene(task, k))
            a, b = on_sumo.traffic, embedded.traffic
            assert a.active.sum() >= 3
            assert np.array_equal(a.active, b.active) and np.array_equal(a.route, b.route)
            assert np.abs(a.progress - b.progress)[a.active].max() < 0.05
            assert np.abs(a.speed - b.speed)[a.active].max() < 0.05
            assert np.hypot(a.x - b.x, a.y - b.y)[a.active].max() < 0.1
            assert abs(on_sumo.world.progress[0, 1] - embedded.world.progress[0, 1]) < 0.3
    finally:
        task.close()


def test_in_traffic_the_north_car_is_sumos_from_the_start():
    """SUMO's insertion checks may refuse the north car among the other vehicles (a vehicle
    added but not inserted reads as SUMO's invalid value): it is put where the scene has it."""
    task = sumo_task(EPISODE, traffic="medium", switching="certified")
    try:
        for k in range(12):
            scene = task.draw_scenarios(2024, np.array([k]), np.zeros(1, dtype=np.int64))
            state = task.initial(scene)
            pose = task.plant.read("north")
            assert pose is not None
            assert abs(pose.speed - scene.north_speed[0]) < 0.05
            assert abs(pose.x - state.world.vehicles.x[0, 1]) < 1e-9
    finally:
        task.close()


@pytest.mark.slow
def test_sumo_drives_the_traffic_and_certified_keeps_the_ego_safe():
    """Whole episodes in heavy traffic under adversaries: vehicles keep entering and leaving
    (SUMO's drivers, handed over from the embedded schedule), the ego never collides by our
    check or SUMO's, the other vehicles never collide with one another, and SUMO's drivers
    keep the certified assumptions."""
    task = sumo_task(EPISODE, traffic="heavy", switching="certified")
    try:
        for k, name in enumerate(("full_throttle", "enter_then_stop", "creep")):
            counts, seen = [], set()

            def watch(state, record, tick, counts=counts, seen=seen):
                tr = state.traffic
                counts.append(int(tr.active.sum()))
                seen.update(int(e) for e in tr.entered[0])

            result = rollout(task, _scene(task, k), catalogue(task, 1, k)[name](), on_tick=watch)
            assert not result.collision[0] and task.sumo_collisions == 0
            assert max(seen) >= 3  # arrivals were handed over and driven
            assert max(counts) >= 6 and min(counts) < max(counts)
            assert not task.assumption_breaks
    finally:
        task.close()


def test_traffic_on_sumo_is_a_gym_environment():
    env = gym.make(
        safeswitch.SUMO_ENV_ID, traffic={"preset": "medium", "observed": 3},
        switching="certified", learned_scope="episode",
    )  # fmt: skip
    embedded = gym.make(safeswitch.TRAFFIC_ENV_ID, traffic={"preset": "medium", "observed": 3})
    try:
        assert env.observation_space == embedded.observation_space
        obs, _ = env.reset(seed=4)
        assert env.observation_space.contains(obs) and obs[6] == 1.0  # a vehicle is observed
        done, info = False, {}
        while not done:
            obs, _, terminated, truncated, info = env.step(np.array([0.4], dtype=np.float32))
            done = terminated or truncated
        assert info["sumo_collisions"] == 0 and not info["assumption_breaks"]
    finally:
        env.close()
        embedded.close()


@pytest.mark.slow
def test_in_traffic_the_oracle_plans_against_the_embedded_scene():
    """Efficiency on SUMO is measured against the same oracle as on the embedded simulator:
    it plans against the embedded scene's drivers (not SUMO's, nor SUMO run a second time)."""
    from safeswitch.app.evaluate import evaluate

    runs = {
        sim: evaluate("rule", None, "random", 3, 5, "certified", None, sim=sim, traffic="light")
        for sim in ("embedded", "sumo")
    }
    embedded, on_sumo = runs["embedded"], runs["sumo"]
    assert on_sumo["mean_oracle_time_to_clear_s"] == embedded["mean_oracle_time_to_clear_s"]
    assert on_sumo["collisions"] == 0 and on_sumo["sumo_collision_episodes"] == 0
