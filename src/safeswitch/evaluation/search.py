"""Open-loop trajectory search on the left turn, alone or in traffic: which sequence of learned
actions clears a scene soonest, and cleanly, under the task's switching logic.

The scene is deterministic given its start (the north car holds its speed; in traffic the other
vehicles follow their rules), so a policy's actions replayed open loop drive exactly its
episode (:func:`policy_actions`, :func:`drive_open_loop`), and a search can start from them.
:func:`search_sequences` is the cross-entropy method per scene; ranked clear first, then by the
*dirty* ticks — a comfort limit broken, the speed limit passed, the filter acting — then
soonest. It serves the ceiling benchmark (``benchmarks/certified_ceiling.py``: what any policy
could clear) and the training pipeline's search-guided refinement
(:mod:`safeswitch.training.refine`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.rollout import Policy, RolloutResult, rollout
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.statistics import comfort_exceeded, speeding
from safeswitch.leftturn.task import LeftTurnTask, StepRecord, TaskState

#: One open-loop action per half second in the structured drivers of :func:`family_of_drivers`.
SEGMENT_S = 0.5  # [s]

#: Scenes searched in one batch (each one ``population`` episodes).
CHUNK = 100

#: Elites of each round of the cross-entropy method.
ELITES = 16

FloatArray = NDArray[np.float64]


def drive_open_loop(
    task: LeftTurnTask, scenarios: Scenarios, actions: FloatArray
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """One episode per row of ``actions`` [B, segments] (the learned action held over each
    segment): the time to clear [s] (NaN: never), the ego's final progress along its route [m]
    and its *dirty* ticks — a comfort limit broken, faster than the tolerated speed, or the
    switching logic's safety action executed.

    Raises:
        AssertionError: an episode collided (under ``certified`` the filter would be broken).
    """
    per_segment = task.config.episode.horizon_ticks // actions.shape[1]
    last: list[FloatArray] = []

    def policy(obs: Any, state: TaskState, tick: int) -> FloatArray:
        return actions[:, min(tick // per_segment, actions.shape[1] - 1)]

    def on_tick(state: TaskState, record: StepRecord, tick: int) -> None:
        last[:] = [state.world.progress[:, 0].copy()]

    result = rollout(task, scenarios, policy, on_tick)
    clear, dirty = _clear_and_dirty(result)
    return clear, last[0], dirty


def _clear_and_dirty(result: RolloutResult) -> tuple[FloatArray, NDArray[np.int64]]:
    """Each episode's time to clear [s] (NaN: never) and dirty ticks.

    Raises:
        AssertionError: an episode collided (under ``certified`` the filter would be broken).
    """
    assert not result.collision.any(), "a collision in an open-loop search episode"
    dirty = result.comfort_violation_steps + result.speeding_steps + result.safety_steps
    return np.asarray(result.time_to_clear, dtype=float), np.asarray(dirty)


def search_sequences(
    task: LeftTurnTask,
    scenarios: Scenarios,
    start: FloatArray | None,
    *,
    population: int,
    rounds: int,
    seed: int,
    seeds: FloatArray | None = None,
    start_std: float = 0.3,
    dirty_cost: float = 10.0,
    knot: int = 1,
    margin: float = 0.0,
    frozen: NDArray[np.int64] | None = None,
) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:
    """The cross-entropy method per scene (:data:`CHUNK` scenes at a time, :data:`ELITES`
    elites): each scene's sequences ranked clear first, then by ``dirty_cost`` [s] per dirty
    tick (10 s: the fewest such ticks before the soonest; 0: the plain time to clear), then
    soonest.

    Args:
        task: The task (its switching logic acts in every episode).
        scenarios: The scenes [n].
        start: Each scene's starting sequence [n, segments] (a policy's own actions, or the best
            simple driver), searched about with ``start_std``; ``None``: about half throttle
            with std 0.8. The start stays in the first round and the best so far in every
            later one, so no scene ends ranked below its start.
        population: Sequences per scene and round.
        rounds: Rounds of the method.
        seed: The random generator's seed.
        seeds: Structured drivers [K, segments] that fill half of the first round.
        start_std: The first round's standard deviation about ``start``.
        dirty_cost: The rank's price of one dirty tick [s].
        knot: Segments per knot of the perturbations: drawn every ``knot`` segments and
            interpolated linearly between (1: independent per segment). A smooth
            perturbation of a policy's smooth actions stays something a policy can fit.
        margin: Each sequence is also driven with every action ``margin`` higher and
            ``margin`` lower (clipped to [-1, 1]), and its dirty ticks are those of all three
            episodes (0: the sequence's own): a sequence clean with its neighbours leaves a
            policy fitted to it, which tracks it only approximately, room before the filter
            or a comfort limit acts. Its time to clear is its own.
        frozen: Per scene, how many leading segments every sequence keeps at ``start``'s
            values [n] (0: none frozen): the search changes only what follows.

    Returns:
        Each scene's best time to clear [s] (NaN: none), its dirty ticks (with ``margin``:
        over the three episodes) and its sequence [n, segments].
    """
    n = len(scenarios.north_speed)
    horizon = task.config.episode.horizon_s
    shaped = start if start is not None else seeds
    if shaped is None:
        raise ValueError("search_sequences needs a start or seeds: they give the sequences' length")
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"search_sequences: margin must be in [0, 1), got {margin!r}")
    segments = shaped.shape[1]
    if frozen is not None and (start is None or np.shape(frozen) != (n,)):
        raise ValueError(
            f"search_sequences: frozen needs a start and one count per scene ({n}), "
            f"got shape {np.shape(frozen)}"
        )
    rng = np.random.default_rng(seed)
    best_clear, best_dirty = np.full(n, np.nan), np.zeros(n, dtype=np.int64)
    best_score, best_seqs = np.full(n, np.inf), np.ones((n, segments))
    for begin in range(0, n, CHUNK):
        idx = np.arange(begin, min(n, begin + CHUNK))
        batch = scenarios.take(np.repeat(idx, population))
        if start is None:
            mean, std = np.full((idx.size, segments), 0.3), np.full((idx.size, segments), 0.8)
        else:
            mean, std = start[idx].copy(), np.full((idx.size, segments), start_std)
        best = np.ones((idx.size, segments))
        for round_ in range(rounds):
            noise = smooth_noise(rng, (idx.size, population, segments), knot)
            seqs = np.clip(mean[:, None, :] + std[:, None, :] * noise, -1.0, 1.0)
            if round_ == 0:  # the structured drivers (and the start) seed the search
                if seeds is not None:
                    k = min(len(seeds), population // 2)
                    seqs[:, :k] = seeds[rng.choice(len(seeds), k, replace=False)]
                if start is not None:
                    seqs[:, 0] = start[idx]
            else:
                seqs[:, 0] = best
            if frozen is not None and start is not None:  # the structured drivers' too
                held = np.arange(segments)[None, :] < frozen[idx][:, None]
                seqs = np.where(held[:, None, :], start[idx][:, None, :], seqs)
            flat = seqs.reshape(-1, segments)
            clear, progress, dirty = drive_open_loop(task, batch, flat)
            for shift in (margin, -margin) if margin > 0 else ():
                dirty = dirty + drive_open_loop(task, batch, np.clip(flat + shift, -1.0, 1.0))[2]
            score = rank_score(clear, progress, horizon) + 1000.0 * np.isnan(clear)
            score = score + dirty_cost * dirty
            score = score.reshape(idx.size, population)
            clear, dirty = clear.reshape(idx.size, population), dirty.reshape(idx.size, population)
            order = np.argsort(score, axis=1)[:, :ELITES]
            elites = np.take_along_axis(seqs, order[:, :, None], axis=1)
            mean, std = elites.mean(axis=1), np.maximum(elites.std(axis=1), 0.05)
            rows, top = np.arange(idx.size), order[:, 0]
            improved = score[rows, top] < best_score[idx]
            best_score[idx[improved]] = score[rows, top][improved]
            best_clear[idx[improved]] = clear[rows, top][improved]
            best_dirty[idx[improved]] = dirty[rows, top][improved]
            best[improved] = seqs[rows, top][improved]
        best_seqs[idx] = best
    return best_clear, best_dirty, best_seqs


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int, int], knot: int) -> FloatArray:
    """Standard normal perturbations of ``shape`` [scenes, population, segments]: independent
    per segment (``knot`` 1), or drawn every ``knot`` segments and interpolated linearly
    between."""
    if knot <= 1:
        return rng.standard_normal(shape)
    *lead, segments = shape
    at = np.arange(0, segments + knot, knot)
    values = rng.standard_normal((*lead, at.size))
    t = np.arange(segments)
    left = np.minimum(t // knot, at.size - 2)
    w = (t - at[left]) / knot
    return np.asarray(values[..., left] * (1 - w) + values[..., left + 1] * w)


def policy_actions(
    task: LeftTurnTask, scenarios: Scenarios, act: Policy
) -> tuple[FloatArray, FloatArray, NDArray[np.int64], NDArray[np.int64]]:
    """A policy's actions [n, decisions] on ``scenarios`` under the task's logic (``act``: a
    rollout policy, e.g. ``load_policy(name).as_policy()``) — replayed open loop, they drive
    exactly its episodes — with each episode's time to clear [s] (NaN: never) and dirty ticks,
    as :func:`drive_open_loop` reports them, and its first dirty tick (−1: none)."""
    config = task.config
    interval = config.episode.decision_interval
    n = len(scenarios.north_speed)
    actions = np.zeros((n, config.episode.horizon_ticks // interval))
    first = np.full(n, -1, dtype=np.int64)
    live = np.ones(n, dtype=bool)

    def policy(obs: Any, state: TaskState, tick: int) -> FloatArray:
        a = np.clip(np.asarray(act(obs, state, tick), dtype=float).reshape(-1), -1.0, 1.0)
        actions[:, tick // interval] = a
        return a

    def on_tick(state: TaskState, record: StepRecord, tick: int) -> None:
        dirty = record.safety_active | comfort_exceeded(record, config) | speeding(record, config)
        first[live & dirty & (first < 0)] = tick
        live[record.terminated | record.truncated] = False

    result = rollout(task, scenarios, policy, on_tick)
    return (actions, *_clear_and_dirty(result), first)


def rank_score(clear: FloatArray, progress: FloatArray, horizon: float) -> FloatArray:
    """Lower is better: the time to clear [s], else the horizon plus 10 s less 0.01 s for
    each metre driven."""
    return np.where(np.isnan(clear), horizon + 10.0 - 0.01 * progress, clear)


def family_of_drivers(segments: int) -> FloatArray:
    """The "drive at a, coast from t1 to t2 (a = −1: the throttle closed), then full throttle"
    drivers (a ∈ {1, 0.5, 0}, t1 ∈ 0…6 s, t2 − t1 ∈ 0.5…6 s), one per row, at
    :data:`SEGMENT_S` per column."""
    rows = []
    t = np.arange(segments) * SEGMENT_S
    for a in (1.0, 0.5, 0.0):
        for t1 in np.arange(0.0, 6.01, SEGMENT_S):
            for hold in np.arange(SEGMENT_S, 6.01, SEGMENT_S):
                rows.append(np.where(t < t1, a, np.where(t < t1 + hold, -1.0, 1.0)))
    return np.array(rows)
