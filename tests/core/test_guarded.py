"""``Guarded``: one switching logic judged by another, through the one supervision step."""

import numpy as np
import pytest

from safeswitch.core.switching import Decision, Guarded, SwitchingError, supervise


class Threshold:
    """Intervenes where the *proposed* action exceeds ``limit``, with ``backup``."""

    def __init__(self, limit: float, backup: float, reason: str):
        self.limit, self.backup = limit, backup
        self.reasons = ("learned", reason)
        self.seen: list[np.ndarray] = []

    def decide(self, state, learned, safe):
        self.seen.append(learned.copy())
        use = learned[:, 0] > self.limit
        return Decision(use, use.astype(np.int8), np.full_like(learned, self.backup))


class WhereFlagged:
    """Intervenes where the state says so, with the Safety controller's action."""

    reasons = ("learned", "flagged")

    def decide(self, state, learned, safe):
        use = np.asarray(state, dtype=bool)
        return Decision(use, use.astype(np.int8), safe)


def test_the_guard_judges_what_the_primary_lets_through_and_wins_where_it_acts():
    guard = Threshold(0.5, -0.5, "too_fast")
    logic = Guarded(WhereFlagged(), guard)
    assert logic.reasons == (
        "learned",
        "flagged",
        "guard:too_fast",
        "guard:too_fast:overrules_primary",
    )
    state = np.array([False, False, True, True])
    learned = np.array([[0.2], [0.9], [0.9], [0.2]])
    safe = np.array([[0.0], [0.0], [0.8], [0.0]])  # row 2: a Safety action the guard refuses
    sup = supervise(logic, state, learned, safe, -1.0, 1.0)
    # what the guard was asked about: the learned action, or the primary's safety action
    np.testing.assert_array_equal(guard.seen[-1][:, 0], [0.2, 0.9, 0.8, 0.0])
    np.testing.assert_array_equal(sup.executed[:, 0], [0.2, -0.5, -0.5, 0.0])
    names = [logic.reasons[r] for r in sup.reason]
    # row 1: the guard replaced a learned action; row 2: the primary's own safety action
    assert names == ["learned", "guard:too_fast", "guard:too_fast:overrules_primary", "flagged"]
    np.testing.assert_array_equal(sup.safety_active, [False, True, True, True])


def test_a_guard_that_never_acts_leaves_the_primary_exactly_as_it_was():
    rng = np.random.default_rng(0)
    state = rng.random(64) < 0.3
    learned = rng.uniform(-1, 1, (64, 1))
    safe = rng.uniform(-1, 1, (64, 1))
    alone = supervise(WhereFlagged(), state, learned, safe, -1.0, 1.0)
    pair = supervise(Guarded(WhereFlagged(), Threshold(2.0, 0.0, "never")), state, learned, safe,
                     -1.0, 1.0)  # fmt: skip
    np.testing.assert_array_equal(pair.executed, alone.executed)
    np.testing.assert_array_equal(pair.reason, alone.reason)


def test_a_malformed_logic_is_named_when_guarded():
    class Broken:
        reasons = ("learned",)

        def decide(self, state, learned, safe):
            return Decision(np.zeros(3, dtype=bool), np.zeros(3, dtype=np.int8), safe)

    logic = Guarded(WhereFlagged(), Broken())
    with pytest.raises(SwitchingError, match=r"Broken\.decide returned Decision\.use_safety"):
        supervise(logic, np.zeros(4, dtype=bool), np.zeros((4, 1)), np.zeros((4, 1)), -1, 1)

    class NoLearned(WhereFlagged):
        reasons = ("x",)

    with pytest.raises(SwitchingError, match="reasons must start with 'learned'"):
        Guarded(WhereFlagged(), NoLearned())
