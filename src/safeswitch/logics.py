"""The ``certified`` switching logic, for every plant that has one.

One name serves each plant with its own certificate: the left turn's
(:mod:`safeswitch.leftturn.logics.certified`) and highway-env's
(:mod:`safeswitch.examples.highway_certified`), chosen by the plant the logic is built for, so
that ``switching="certified"`` means the same promise everywhere: a learned action is executed
only if the Safety controller can still keep the ego out of every other vehicle, within stated
assumptions about the others.
"""

from __future__ import annotations

from typing import Any

from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import SwitchingLogic
from safeswitch.leftturn.views import LogicScene


def certified_logic(context: object) -> SwitchingLogic[Any]:
    """Factory of the ``certified`` logic (registered under that name): the left turn's for a
    left-turn scene, highway-env's for a highway-env environment.

    Raises:
        LogicContextError: A plant with no certified logic (named).
    """
    if isinstance(context, LogicScene):
        from safeswitch.leftturn.logics.certified import certified_logic as left_turn

        return left_turn(context)
    # highway-env (and Gymnasium) are imported only for a plant that is not the left turn: the
    # deployment runtime builds the left turn's without either installed
    from safeswitch.examples.highway import is_highway

    if is_highway(context):
        from safeswitch.examples.highway_certified import certified_highway_logic

        return certified_highway_logic(context)
    raise LogicContextError(
        "the 'certified' switching logic supervises the left turn and highway-env, not "
        f"{context_name(context)}"
    )
