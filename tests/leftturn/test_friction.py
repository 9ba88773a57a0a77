"""Tyre friction in the left turn (issue #37): no controller, learned or adversarial, takes a
vehicle beyond ``μ·g``; too fast into the turn the ego's tyres slide and it loses control — a
failure, counted beside collisions — unless the certified logic keeps it within its curve
speeds; the other drivers take their turns within the circle too."""

import numpy as np
import pytest

from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.sim.params import GRAVITY
from safeswitch.sim.streams import TURN_LATERAL_ACCEL

EPISODE = {"episode": {"learned_scope": "episode"}}
MU_G = 0.9 * GRAVITY  # the default tyres


def task_for(switching):
    return LeftTurnTask(resolve_config(EPISODE, switching=switching))


@pytest.mark.parametrize("switching", ["none", "paper", "certified"])
@pytest.mark.parametrize("adversary", ["full_throttle", "bang_bang", "uniform"])
def test_no_controller_takes_the_ego_beyond_the_friction_circle(switching, adversary):
    task = task_for(switching)
    scenarios = task.scenario_set(11, 400)
    worst = [0.0]

    def watch(state, record, tick):
        worst[0] = max(worst[0], float(np.hypot(record.accel_lon, record.accel_lat).max()))

    rollout(task, scenarios, catalogue(task, 400, 2)[adversary](), watch)
    assert worst[0] <= MU_G * (1 + 1e-9)


def test_full_throttle_into_the_turn_loses_control_and_counts_as_a_failure():
    """Without a logic that knows the curve (none, and the paper's, which brakes for the north
    car only), full throttle slides off the lane: the episode ends, ``lost_control`` in its
    info, a failure in every summary. The certified logic keeps the same driver on its lane."""
    for switching in ("none", "paper"):
        task = task_for(switching)
        scenarios = task.scenario_set(11, 300)
        result = rollout(task, scenarios, catalogue(task, 300, 2)["full_throttle"]())
        lost = result.lost_control
        assert lost.sum() > 100, switching
        assert (result.max_lateral[lost] > task.config.geometry.lane_width / 2).all()
        summary = summarize(result)
        assert summary["lost_control_episodes"] == int(lost.sum())
        assert summary["failures"] == int((lost | result.collision).sum())
    task = task_for("certified")
    result = rollout(task, task.scenario_set(11, 300), catalogue(task, 300, 2)["full_throttle"]())
    assert result.lost_control.sum() == 0 and result.collision.sum() == 0


def test_a_slide_ends_the_step_with_lost_control_in_the_info():
    import gymnasium as gym

    import safeswitch  # noqa: F401

    env = gym.make("safeswitch/LeftTurn-v0", switching="none", learned_scope="episode",
                   scenario="cut")  # fmt: skip
    env.reset(seed=0)
    for _ in range(600):
        _, _, terminated, truncated, info = env.step(np.array([1.0], dtype=np.float32))
        if terminated or truncated:
            break
    assert terminated and info["lost_control"] and not info["collision"]


def test_cut_and_yield_add_up_to_the_cleared_episodes():
    """``cut``: the ego cleared its zone before the north car left its own; ``yield``: after;
    an episode that never cleared is neither (it was counted as a yield before)."""
    for switching, adversary in (
        ("paper", "uniform"),
        ("certified", "creep"),
        ("none", "zero_throttle"),
    ):
        task = task_for(switching)
        result = rollout(task, task.scenario_set(5, 500), catalogue(task, 500, 3)[adversary]())
        s = summarize(result)
        assert s["cut_episodes"] + s["yield_episodes"] == s["cleared_episodes"], (switching, s)
        assert s["never_cleared_episodes"] == s["episodes"] - s["cleared_episodes"]
    assert s["never_cleared_episodes"] > 0  # a car that never moves clears nothing


def test_the_other_drivers_take_their_turns_within_the_friction_circle():
    """The drivers of the streams brake for the turns (their speeds within
    ``TURN_LATERAL_ACCEL``) and their pedals get only what cornering leaves of ``μ·g``."""
    task = build_task(None, {"switching": "certified", **EPISODE}, traffic="heavy")
    state = task.initial(task.scenario_set(7, 64))
    tables = task.tables
    worst_lateral = worst_combined = 0.0
    for _ in range(900):
        state, _ = task.step(state, np.zeros(64))
        tr = state.traffic
        index = np.clip((tr.progress // tables.spacing).astype(int), 0, tables.size - 1)
        kappa = tables.curvature[tr.route, index]
        lateral = np.where(tr.active, tr.speed**2 * kappa, 0.0)
        combined = np.where(tr.active, np.hypot(tr.accel, lateral), 0.0)
        worst_lateral = max(worst_lateral, float(lateral.max()))
        worst_combined = max(worst_combined, float(combined.max()))
    assert worst_lateral <= 1.2 * TURN_LATERAL_ACCEL  # they slow for the turns
    assert worst_combined <= MU_G * (1 + 1e-9)
