"""Switching logics and the supervision step that applies them (paper Fig. 1, plant-agnostic).

Both candidate actions are expressed in the plant's input space, shape ``[B, A]``. A switching
logic looks at the plant state and both candidates and decides, per element, whether a safety
action replaces the learned one, which safety action (the Safety controller's, or one of the
logic's own backups), and why.

:func:`supervise` is *the* runtime path: every case study (the left turn's task, the
:class:`~safeswitch.core.wrappers.SafeSwitch` wrappers around any Gymnasium env) runs its
switching through it. It wraps any logic with the checks that must hold whatever the logic does:

* a learned action with a NaN or infinite component is never executed. In its place the
  *fallback* action is proposed — by default the Safety controller's; the wrappers and the left
  turn hold the last command instead (a zero-order hold: braking wherever the car happens to
  be can stop it in the other car's path) — and the logic decides about it as about any
  proposal. The tick counts as an intervention (``safety_active``; reason
  ``invalid_learned_action``): the learned controller was not used;
* finite learned actions are clipped to the input bounds *before* the logic sees them, so the
  logic judges exactly what would be executed;
* every executed action is finite and inside the bounds;
* the logic's :class:`Decision` is checked (shapes, dtypes, reason codes, finite safety
  actions): a logic that breaks its contract fails loudly, naming itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from safeswitch.core.arrays import jit

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int8]

StateT_contra = TypeVar("StateT_contra", contravariant=True)

#: Name added by :func:`supervise` for a learned action that was NaN or infinite.
INVALID_LEARNED_ACTION = "invalid_learned_action"


class SwitchingError(ValueError):
    """A switching logic, a Safety controller or an action broke its contract; the message
    names which and how."""


@dataclass
class Decision:
    """A switching logic's decision for a batch.

    Attributes:
        use_safety: Execute ``safe_action`` instead of the learned action ``[B]`` (bool).
        reason: Reason code into the logic's ``reasons`` ``[B]`` (int8; 0 = ``"learned"``).
        safe_action: The safety action to execute where ``use_safety`` ``[B, A]``: the Safety
            controller's action, or a backup of the logic's own.
    """

    use_safety: BoolArray
    reason: IntArray
    safe_action: FloatArray


@runtime_checkable
class SwitchingLogic(Protocol[StateT_contra]):
    """Chooses, per element, between the learned action and a safety action.

    Attributes:
        reasons: Names of the decisions this logic can report; index 0 is ``"learned"``.
    """

    reasons: tuple[str, ...]

    def decide(self, state: StateT_contra, learned: FloatArray, safe: FloatArray) -> Decision:
        """Decide for every element of the batch.

        Args:
            state: The plant state as this logic needs it (batched).
            learned: Learned actions ``[B, A]``, finite and within the input bounds.
            safe: The Safety controller's actions ``[B, A]``.
        """
        ...


class NeverSwitch:
    """The learned action always (``switching="none"``): no safety net."""

    reasons: tuple[str, ...] = ("learned",)

    def decide(self, state: object, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        return Decision(np.zeros(batch, dtype=bool), np.zeros(batch, dtype=np.int8), safe)


def never_switch(context: object = None) -> NeverSwitch:
    """Factory of the ``none`` logic (registered under that name); any plant."""
    return NeverSwitch()


class Guarded:
    """One logic guarded by another: ``primary`` decides, then ``guard`` judges the action
    ``primary`` lets through (the learned one, or ``primary``'s safety action) exactly as it
    would judge a learned proposal, and its safety action wins where it intervenes.

    Whatever the guard guarantees for any proposed action sequence (the ``certified`` logic:
    no collision) therefore holds for the pair, while ``primary`` still decides everywhere the
    guard lets it. The pair's safety action is executed where either intervened.

    Args:
        primary: The logic in the loop (e.g. the paper's Algorithm 1).
        guard: The logic beneath it (e.g. the certified safety filter).

    Attributes:
        reasons: ``primary``'s reasons; then the guard's, each prefixed ``"guard:"`` (the
            guard replaced a learned action the primary let through); then the guard's again,
            each also suffixed ``":overrules_primary"`` (the guard replaced the primary's own
            safety action: the primary's safety net was itself unsafe there).
    """

    def __init__(self, primary: SwitchingLogic[Any], guard: SwitchingLogic[Any]) -> None:
        first, second = check_logic(primary), check_logic(guard)
        self.primary, self.guard = primary, guard
        self._offset = len(first) - 1
        self._overrules = len(second) - 1
        self.reasons: tuple[str, ...] = (
            *first,
            *(f"guard:{r}" for r in second[1:]),
            *(f"guard:{r}:overrules_primary" for r in second[1:]),
        )
        check_logic(self)

    def decide(self, state: Any, learned: FloatArray, safe: FloatArray) -> Decision:
        batch, dim = learned.shape
        first = check_decision(self.primary, self.primary.decide(state, learned, safe), batch, dim)
        use_first = first.use_safety[:, None]
        passed = np.where(use_first, first.safe_action, learned)
        second = check_decision(self.guard, self.guard.decide(state, passed, safe), batch, dim)
        use = first.use_safety | second.use_safety
        action = np.where(second.use_safety[:, None], second.safe_action, passed)
        guard_reason = second.reason.astype(np.int16) + self._offset
        guard_reason += np.where(first.use_safety, self._overrules, 0).astype(np.int16)
        reason = np.where(second.use_safety, guard_reason, first.reason).astype(np.int8)
        return Decision(use, reason, action)


def check_logic(logic: object) -> tuple[str, ...]:
    """The logic's reasons, after checking that it follows :class:`SwitchingLogic`.

    Raises:
        SwitchingError: No ``decide`` method, or ``reasons`` is not a non-empty tuple of
            distinct strings starting with ``"learned"`` (at most 126 of them).
    """
    name = type(logic).__name__
    if not callable(getattr(logic, "decide", None)):
        raise SwitchingError(f"switching logic {name} has no decide(state, learned, safe) method")
    reasons = getattr(logic, "reasons", None)
    if (
        not isinstance(reasons, tuple)
        or not reasons
        or not all(isinstance(r, str) for r in reasons)
        or len(set(reasons)) != len(reasons)
    ):
        raise SwitchingError(
            f"switching logic {name}: reasons must be a tuple of distinct strings, got {reasons!r}"
        )
    if reasons[0] != "learned":
        raise SwitchingError(
            f"switching logic {name}: reasons must start with 'learned', got {reasons!r}"
        )
    if INVALID_LEARNED_ACTION in reasons or len(reasons) > 126:
        raise SwitchingError(
            f"switching logic {name}: reasons may not contain {INVALID_LEARNED_ACTION!r} "
            f"(added by the supervisor) and must number at most 126, got {reasons!r}"
        )
    return reasons


def reason_names(logic: SwitchingLogic[Any]) -> tuple[str, ...]:
    """The full reason table of a supervised logic: its own, then the invalid-action reason."""
    return (*check_logic(logic), INVALID_LEARNED_ACTION)


def check_decision(logic: SwitchingLogic[Any], decision: object, batch: int, dim: int) -> Decision:
    """``decision`` if its fields have the shapes and dtypes of an answer of ``logic`` for a
    batch of ``batch`` actions of ``dim`` components (:func:`supervise` checks the values:
    reason codes in range, finite safety actions where chosen).

    Raises:
        SwitchingError: Naming the logic and the field of the decision that is wrong.
    """
    name = type(logic).__name__
    if not isinstance(decision, Decision):
        raise SwitchingError(f"{name}.decide must return a Decision, got {type(decision)!r}")
    d = decision
    for field, value, shape, kinds in (
        ("use_safety", d.use_safety, (batch,), "b"),
        ("reason", d.reason, (batch,), "iu"),
        ("safe_action", d.safe_action, (batch, dim), "f"),
    ):
        if (
            not isinstance(value, np.ndarray)
            or value.shape != shape
            or value.dtype.kind not in kinds
        ):
            got = (
                f"{value.dtype} array of shape {value.shape}"
                if isinstance(value, np.ndarray)
                else repr(type(value))
            )
            want = {"b": "bool", "iu": "integer", "f": "float"}[kinds]
            raise SwitchingError(
                f"{name}.decide returned Decision.{field} as {got}; expected a {want} array "
                f"of shape {shape}"
            )
    return d


@dataclass
class Supervision:
    """What the supervisor decided on one tick, for the record and for the reward.

    Attributes:
        learned: The learned action as proposed (NaN kept, so the record shows it) ``[B, A]``.
        safe: The Safety controller's action ``[B, A]``.
        executed: The action sent to the plant ``[B, A]`` — always finite and in bounds.
        safety_active: Whether the learned action was overridden: a safety action was
            executed (the paper's ``s*``), or the learned action was invalid ``[B]``.
        use_safety: Whether the logic chose its safety action ``[B]`` (``safety_active``
            without the invalid-action ticks whose fallback the logic accepted).
        reason: Reason code into :func:`reason_names` ``[B]``.
        valid: Whether the learned action was finite ``[B]``.
        clipped: Whether a finite learned action lay outside the bounds and was clipped ``[B]``.
    """

    learned: FloatArray
    safe: FloatArray
    executed: FloatArray
    safety_active: BoolArray
    use_safety: BoolArray
    reason: IntArray
    valid: BoolArray
    clipped: BoolArray


def supervise(
    logic: SwitchingLogic[StateT_contra],
    state: StateT_contra,
    learned: ArrayLike,
    safe: ArrayLike,
    low: ArrayLike,
    high: ArrayLike,
    fallback: ArrayLike | None = None,
) -> Supervision:
    """One supervision step: the learned action checked, the logic's decision, the executed
    action (see the module docstring for the rules).

    Args:
        logic: The switching logic.
        state: Plant state for the logic.
        learned: Learned actions ``[B, A]`` in the plant's input space (may hold NaN/inf).
        safe: The Safety controller's actions ``[B, A]`` (must be finite).
        low: Lower input bounds (scalar or ``[A]``).
        high: Upper input bounds (scalar or ``[A]``).
        fallback: What is proposed in place of an invalid learned action ``[B, A]``
            (default: ``safe``); must be finite where it is used.

    Raises:
        SwitchingError: The Safety controller's action or a used fallback is NaN or infinite,
            a shape does not match, or the logic broke its contract.
    """
    learned = np.asarray(learned, dtype=np.float64)
    safe = np.asarray(safe, dtype=np.float64)
    if learned.ndim != 2 or safe.shape != learned.shape:
        raise SwitchingError(
            f"learned and safety actions must both have shape [B, A]; got {learned.shape} and "
            f"{safe.shape}"
        )
    batch, dim = learned.shape
    backup = safe if fallback is None else np.asarray(fallback, dtype=np.float64)
    if backup.shape != learned.shape:
        raise SwitchingError(f"fallback actions of shape {backup.shape}; expected {learned.shape}")
    bounds = np.empty((2, dim))
    bounds[0], bounds[1] = low, high
    candidate = np.empty((batch, dim))
    valid = np.empty(batch, dtype=np.bool_)
    clipped = np.empty(batch, dtype=np.bool_)
    problem = _propose(learned, safe, backup, bounds, candidate, valid, clipped)
    if problem == 1:
        raise SwitchingError("the Safety controller returned a NaN or infinite action")
    if problem == 2:
        raise SwitchingError("the fallback for an invalid learned action is NaN or infinite")
    decision = check_decision(logic, logic.decide(state, candidate, safe), batch, dim)
    executed = np.empty((batch, dim))
    reason = np.empty(batch, dtype=np.int8)
    active = np.empty(batch, dtype=np.bool_)
    problem = _execute(
        decision.use_safety, decision.reason, decision.safe_action, candidate, valid, bounds,
        len(logic.reasons), executed, reason, active,
    )  # fmt: skip
    if problem == 1:
        raise SwitchingError(
            f"{type(logic).__name__}.decide returned a reason code outside "
            f"0..{len(logic.reasons) - 1} (its reasons: {logic.reasons})"
        )
    if problem == 2:
        raise SwitchingError(
            f"{type(logic).__name__}.decide chose a safety action that is NaN or infinite"
        )
    return Supervision(learned, safe, executed, active, decision.use_safety, reason, valid, clipped)


@jit
def _propose(
    learned: FloatArray, safe: FloatArray, fallback: FloatArray, bounds: FloatArray,
    candidate: FloatArray, valid: BoolArray, clipped: BoolArray,
) -> int:  # fmt: skip
    """What the logic is asked about, per element: the learned action clipped to ``bounds``
    (rows low, high), or the fallback where a component is NaN/inf. Returns 0, or 1 if a
    safety action is not finite, 2 if a used fallback is not finite."""
    batch, dim = learned.shape
    for b in range(batch):
        ok = True
        for j in range(dim):
            if not math.isfinite(safe[b, j]):
                return 1
            ok = ok and math.isfinite(learned[b, j])
        valid[b] = ok
        source = learned if ok else fallback
        changed = False
        for j in range(dim):
            value = source[b, j]
            if not math.isfinite(value):
                return 2
            inside = min(max(value, bounds[0, j]), bounds[1, j])
            candidate[b, j] = inside
            changed = changed or inside != value
        clipped[b] = ok and changed
    return 0


@jit
def _execute(
    use: BoolArray, reason: NDArray[Any], safe_action: FloatArray, candidate: FloatArray,
    valid: BoolArray, bounds: FloatArray, n_reasons: int, executed: FloatArray,
    reason_out: IntArray, active: BoolArray,
) -> int:  # fmt: skip
    """The executed actions (the logic's safety action, clipped, where it chose it; else the
    candidate) and the reason codes (``n_reasons`` — the invalid-action code — where the learned
    action was invalid), and whether the learned action was overridden (``active``). Returns 0,
    or 1 for a reason code out of range, 2 for a chosen safety action that is not finite."""
    batch, dim = candidate.shape
    for b in range(batch):
        code = reason[b]
        if code < 0 or code >= n_reasons:
            return 1
        reason_out[b] = code if valid[b] else n_reasons
        active[b] = use[b] or not valid[b]
        for j in range(dim):
            if use[b]:
                value = safe_action[b, j]
                if not math.isfinite(value):
                    return 2
                executed[b, j] = min(max(value, bounds[0, j]), bounds[1, j])
            else:
                executed[b, j] = candidate[b, j]
    return 0


def intervention_penalty(safety_active: BoolArray, penalty: float) -> FloatArray:
    """The switching logic's feedback to the learner (paper Eq. 4): ``penalty`` on every tick
    where a safety action was executed, else 0."""
    return np.where(safety_active, penalty, 0.0)
