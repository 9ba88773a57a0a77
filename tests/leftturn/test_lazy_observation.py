"""A tick observes only when someone reads the observation: a held decision's last tick, an
episode's end, the tick before a rollout's decision. What every consumer sees is what it saw
when every tick observed, bit for bit (in traffic the observation is most of a tick's cost)."""

from dataclasses import fields

import numpy as np
import pytest

from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import LeftTurnTask, StepRecord

from .test_traffic import _write_go_model

#: Traffic with every per-tick observation cost: the filter's margins, the clock, a go model;
#: no switching logic (collisions) and a short horizon, so that episodes end inside a held decision.
SCENE = {"switching": "none", "episode": {"decision_interval": 15, "observe_time_left": True}}
TRAFFIC = {"preset": "heavy", "observe": "margins", "horizon_s": 7.3}  # 365 ticks: mid-hold


@pytest.fixture(scope="module")
def task(tmp_path_factory):
    width = build_task(None, SCENE, traffic=TRAFFIC).observation_bounds[0].shape[0]
    model = _write_go_model(tmp_path_factory.mktemp("go") / "go.npz", width)
    return build_task(None, SCENE, traffic={**TRAFFIC, "go_model": model})


class Counting:
    """``task`` with its :meth:`~LeftTurnTask.step` counting the ticks that observed, or
    (``eager``) made to observe every tick, as before ticks could skip it."""

    def __init__(self, task: LeftTurnTask, eager: bool) -> None:
        self.task, self.eager, self.observed, self.ticks = task, eager, 0, 0

    def __enter__(self) -> "Counting":
        original = type(self.task).step

        def step(task, state, action, observe=True):
            state, record = original(task, state, action, True if self.eager else observe)
            self.ticks += 1
            self.observed += record.observation is not None
            return state, record

        self.task.step = step.__get__(self.task)
        return self

    def __exit__(self, *exc: object) -> None:
        del self.task.step


def assert_same_record(a: StepRecord, b: StepRecord) -> None:
    for f in fields(StepRecord):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "terms":
            assert x.keys() == y.keys()
            for name in x:
                np.testing.assert_array_equal(x[name], y[name], err_msg=name)
        else:
            np.testing.assert_array_equal(x, y, err_msg=f.name)


def held_decisions(task: LeftTurnTask, eager: bool) -> tuple[list[StepRecord], int, int]:
    ids = np.arange(48)
    state = task.initial(task.draw_scenarios(11, ids, np.zeros_like(ids)))
    rng = np.random.default_rng(3)
    records = []
    with Counting(task, eager) as counting:
        for _ in range(task.config.episode.horizon_ticks // 15 + 1):
            state, record = task.hold(state, rng.uniform(-1, 1, 48))
            records.append(record)
    return records, counting.observed, counting.ticks


def test_a_held_decision_observes_only_where_it_ends_and_gives_the_same_record(task):
    lazy, observed, ticks = held_decisions(task, eager=False)
    eager, _, eager_ticks = held_decisions(task, eager=True)
    assert ticks == eager_ticks
    for a, b in zip(lazy, eager, strict=True):
        assert_same_record(a, b)  # the observation of every episode included
    ends = [int((r.terminated | r.truncated).sum()) for r in lazy]
    assert sum(ends) > 20  # collisions without a logic, and the horizon: episodes end mid-hold
    assert len(lazy) <= observed < ticks / 3  # a few of the ticks: the decisions' and the ends'


def test_a_rollout_observes_only_before_a_decision_and_its_policy_sees_the_same(task):
    ids = np.arange(48)
    scenes = task.draw_scenarios(12, ids, np.zeros_like(ids))

    def run(eager):
        seen, rng = [], np.random.default_rng(4)

        def policy(observation, state, tick):
            seen.append(observation.copy())
            return rng.uniform(-1, 1, 48)

        with Counting(task, eager) as counting:
            result = rollout(task, scenes, policy)
        return seen, result, counting.observed, counting.ticks

    seen, result, observed, ticks = run(eager=False)
    seen_eager, result_eager, _, _ = run(eager=True)
    assert len(seen) == len(seen_eager) > 5
    for a, b in zip(seen, seen_eager, strict=True):
        np.testing.assert_array_equal(a, b)
    for f in fields(result):
        x, y = getattr(result, f.name), getattr(result_eager, f.name)
        for name in x if isinstance(x, dict) else [None]:
            np.testing.assert_array_equal(
                x if name is None else x[name], y if name is None else y[name]
            )
    assert observed == len(seen) - 1 or observed == len(seen)  # one before each decision
    assert observed < ticks / 10


def test_a_record_without_its_observation_says_so(task):
    ids = np.arange(4)
    state = task.initial(task.draw_scenarios(1, ids, np.zeros_like(ids)))
    _, record = task.step(state, np.zeros(4), observe=False)
    assert record.observation is None
    with pytest.raises(RuntimeError, match="observe=False"):
        record.observed  # noqa: B018
    _, record = task.step(state, np.zeros(4))
    assert record.observed.shape == (4, task.observation_bounds[0].shape[0])
