"""Switching logics as plugins, registered by name.

A *factory* builds a logic for one plant: ``factory(context) -> SwitchingLogic``, where the
context is whatever the plant's code hands over — the left-turn task for its logics, the
wrapped environment for :class:`~safeswitch.core.wrappers.SafeSwitch`. A factory that cannot
serve the context it is given raises :class:`LogicContextError`, naming the plant it needs.

Logics come from two places:

* :func:`register_logic` at run time (``register_logic("mylogic", MyLogic)``);
* the entry-point group ``safeswitch.logics`` of any installed distribution, e.g. in its
  ``pyproject.toml``::

      [project.entry-points."safeswitch.logics"]
      mylogic = "mypackage.logics:make_my_logic"

  safeswitch's own ``paper``, ``certified`` and ``none`` are declared exactly so. Entry points
  are read once, the first time a name is looked up, and loaded only when used.

Once known, ``switching="mylogic"`` works in ``gymnasium.make``, in configuration files and on
the command line, without editing the package.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from typing import Any

from safeswitch.core.switching import SwitchingError, SwitchingLogic, check_logic

#: The entry-point group third-party packages declare their logics in.
ENTRY_POINT_GROUP = "safeswitch.logics"

LogicFactory = Callable[[Any], SwitchingLogic[Any]]

_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_.-]*$")
_registered: dict[str, LogicFactory] = {}
_entry_points: dict[str, metadata.EntryPoint] | None = None


class LogicContextError(SwitchingError):
    """A registered logic was asked to supervise a plant it was not written for."""


def context_name(context: Any) -> str:
    """How a :class:`LogicContextError` names the plant a logic was offered: a Gymnasium
    environment by its id (a wrapper's class name says nothing to its user), anything else by
    its type."""
    spec = getattr(context, "spec", None)
    env_id = getattr(spec, "id", None)
    if isinstance(env_id, str):
        return env_id
    return type(context).__name__


class UnknownLogicError(SwitchingError, KeyError):
    """No logic is registered under a name."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0])


def register_logic(name: str, factory: LogicFactory, *, replace: bool = False) -> None:
    """Make ``factory`` available as the switching logic ``name``.

    Args:
        name: Letters, digits, ``_``, ``.`` and ``-``, starting with a letter.
        factory: ``factory(context) -> SwitchingLogic`` (a logic class taking the context
            works too).
        replace: Allow replacing a logic registered under the same name.

    Raises:
        ValueError: A malformed name, a factory that is not callable, or a name already taken
            (without ``replace``).
    """
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(
            f"logic name {name!r} must start with a letter and hold only letters, digits, "
            "'_', '.' and '-'"
        )
    if not callable(factory):
        raise ValueError(f"the factory of logic {name!r} is not callable: {factory!r}")
    if name in _registered and not replace:
        raise ValueError(f"a switching logic named {name!r} is already registered")
    _registered[name] = factory


def unregister_logic(name: str) -> None:
    """Forget a logic registered with :func:`register_logic` (entry points stay)."""
    _registered.pop(name, None)


def _discovered() -> dict[str, metadata.EntryPoint]:
    global _entry_points
    if _entry_points is None:
        found = metadata.entry_points(group=ENTRY_POINT_GROUP)
        _entry_points = {ep.name: ep for ep in found}
    return _entry_points


def refresh_entry_points() -> None:
    """Read the ``safeswitch.logics`` entry points again (after installing a plugin in a
    running interpreter)."""
    global _entry_points
    _entry_points = None


def logic_names() -> tuple[str, ...]:
    """Every known logic name, sorted: registered at run time and declared as entry points."""
    return tuple(sorted(set(_registered) | set(_discovered())))


def logic_factory(name: str) -> LogicFactory:
    """The factory registered as ``name`` (a run-time registration wins over an entry point).

    Raises:
        UnknownLogicError: Naming the known logics.
    """
    if name in _registered:
        return _registered[name]
    entry = _discovered().get(name)
    if entry is None:
        known = ", ".join(logic_names()) or "none"
        raise UnknownLogicError(f"unknown switching logic {name!r}; known logics: {known}")
    factory = entry.load()
    if not callable(factory):
        raise SwitchingError(
            f"entry point {name!r} of group {ENTRY_POINT_GROUP!r} ({entry.value}) is not callable"
        )
    _registered[name] = factory
    return factory


def make_logic(name: str, context: Any) -> SwitchingLogic[Any]:
    """The logic ``name`` built for ``context``, checked against the protocol.

    Raises:
        UnknownLogicError: No such logic.
        LogicContextError: The logic does not serve this kind of plant.
        SwitchingError: The factory's result is not a valid switching logic.
    """
    logic = logic_factory(name)(context)
    check_logic(logic)
    return logic


def resolve_logic(logic: SwitchingLogic[Any] | str, context: Any) -> SwitchingLogic[Any]:
    """A logic object as given (checked), or the registered logic of that name."""
    if isinstance(logic, str):
        return make_logic(logic, context)
    check_logic(logic)
    return logic


@dataclass(frozen=True)
class RegisteredController:
    """A Safety controller registered for a Gymnasium id.

    Attributes:
        factory: ``factory(env) -> safety_controller`` (``safety_controller(state) -> [B, A]``).
        state_fn: ``state_fn(env) -> state`` for :class:`~safeswitch.core.wrappers.SafeSwitch`
            (``None``: the last observation).
    """

    factory: Callable[[Any], Callable[[Any], Any]]
    state_fn: Callable[[Any], Any] | None = None


_controllers: dict[str, RegisteredController] = {}


def register_safety_controller(
    env_id: str,
    factory: Callable[[Any], Callable[[Any], Any]],
    *,
    state_fn: Callable[[Any], Any] | None = None,
) -> None:
    """Register the Safety controller of the environments ``env_id``, so that ``safeswitch
    train --env ENV_ID --switching LOGIC`` can wrap them in
    :class:`~safeswitch.core.wrappers.SafeSwitch`.

    Args:
        env_id: A Gymnasium id.
        factory: ``factory(env) -> safety_controller``.
        state_fn: What the controller and the logic see (default: the last observation).
    """
    if not callable(factory):
        raise ValueError(f"the Safety controller factory of {env_id!r} is not callable")
    _controllers[env_id] = RegisteredController(factory, state_fn)


def safety_controller_for(env_id: str) -> RegisteredController | None:
    """The Safety controller registered for ``env_id``, if any."""
    return _controllers.get(env_id)
