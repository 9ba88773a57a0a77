"""Switching logics and the supervisor that applies them (paper Fig. 1, plant-agnostic).

Both candidate actions are expressed in the plant's input space, shape ``[B, A]``. A switching
logic looks at the plant state and both candidates and decides, per element, whether a safety
action replaces the learned one, which safety action (the Safety controller's, or one of the
logic's own backups), and why. :func:`supervise` wraps any logic with the checks that must hold
whatever the logic does: a learned action that is NaN or infinite is never executed (the safety
side decides instead), and every executed action is inside the plant's input bounds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import clamp

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int8]

StateT_contra = TypeVar("StateT_contra", contravariant=True)

#: Name added by :func:`supervise` for a learned action that was NaN or infinite.
INVALID_LEARNED_ACTION = "invalid_learned_action"


@dataclass
class Decision:
    """A switching logic's decision for a batch.

    Attributes:
        use_safety: Execute ``safe_action`` instead of the learned action ``[B]``.
        reason: Reason code into the logic's ``reasons`` ``[B]``.
        safe_action: The safety action to execute where ``use_safety`` ``[B, A]``: the Safety
            controller's action, or a backup of the logic's own.
    """

    use_safety: BoolArray
    reason: IntArray
    safe_action: FloatArray


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


def reason_names(logic: SwitchingLogic[StateT_contra]) -> tuple[str, ...]:
    """The full reason table of a supervised logic: its own, then the invalid-action reason."""
    if not logic.reasons or logic.reasons[0] != "learned":
        raise ValueError(f"a switching logic's reasons must start with 'learned': {logic.reasons}")
    return (*logic.reasons, INVALID_LEARNED_ACTION)


@dataclass
class Supervision:
    """What the supervisor decided on one tick, for the record and for the reward.

    Attributes:
        learned: The learned action as proposed (NaN kept, so the record shows it) ``[B, A]``.
        safe: The Safety controller's action ``[B, A]``.
        executed: The action sent to the plant ``[B, A]`` — always finite and in bounds.
        safety_active: Whether a safety action was executed (the paper's ``s*``) ``[B]``.
        reason: Reason code into :func:`reason_names` ``[B]``.
    """

    learned: FloatArray
    safe: FloatArray
    executed: FloatArray
    safety_active: BoolArray
    reason: IntArray


def supervise(
    logic: SwitchingLogic[StateT_contra],
    state: StateT_contra,
    learned: FloatArray,
    safe: FloatArray,
    low: FloatArray | float,
    high: FloatArray | float,
) -> Supervision:
    """Apply a switching logic with the checks that hold for every logic.

    A learned action with a NaN or infinite component is not valid: the logic is asked about the
    Safety controller's action in its place, and whatever is then executed counts as a safety
    action with the reason ``invalid_learned_action``. Finite learned actions are clipped to
    ``[low, high]`` before the logic sees them, so the logic judges exactly what would be
    executed.

    Args:
        logic: The switching logic.
        state: Plant state for the logic.
        learned: Learned actions ``[B, A]`` in the plant's input space.
        safe: The Safety controller's actions ``[B, A]``.
        low: Lower input bounds (scalar or ``[A]``).
        high: Upper input bounds.
    """
    learned = np.asarray(learned, dtype=np.float64)
    valid: BoolArray = np.asarray(np.isfinite(learned).all(axis=-1))
    candidate = clamp(np.where(valid[:, None], learned, safe), low, high)
    decision = logic.decide(state, candidate, safe)
    executed = np.where(
        decision.use_safety[:, None], clamp(decision.safe_action, low, high), candidate
    )
    invalid_code = np.int8(len(logic.reasons))
    reason = np.where(valid, decision.reason, invalid_code).astype(np.int8)
    return Supervision(learned, safe, executed, decision.use_safety | ~valid, reason)


def intervention_penalty(safety_active: BoolArray, penalty: float) -> FloatArray:
    """The switching logic's feedback to the learner (paper Eq. 4): ``penalty`` on every tick
    where a safety action was executed, else 0."""
    return np.where(safety_active, penalty, 0.0)
