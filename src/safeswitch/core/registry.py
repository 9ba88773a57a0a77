"""Switching logics as plugins, registered by name.

A *factory* builds a logic for one plant: ``factory(context) -> SwitchingLogic``, where the
context is whatever the plant's code hands over — the left-turn task for its logics, the
wrapped environment for :class:`~safeswitch.core.wrappers.SafeSwitch`. A factory that cannot
serve the context it is given raises :class:`LogicContextError`, naming the plant it needs.

Logics come from two places:

* :func:`register_logic` at run time (``register_logic("mylogic", MyLogic)``, or with the
  class of its parameters, ``register_logic("mylogic", make, config=MyParams)``);
* the entry-point group ``safeswitch.logics`` of any installed distribution, e.g. in its
  ``pyproject.toml``::

      [project.entry-points."safeswitch.logics"]
      mylogic = "mypackage.logics:make_my_logic"

  safeswitch's own ``paper``, ``certified`` and ``none`` are declared exactly so. An entry
  point names either a factory or a :class:`LogicPlugin` (a factory with the class of its
  parameters). Entry points are read once, the first time a name is looked up, and loaded
  only when used.

Once known, ``switching="mylogic"`` works in ``gymnasium.make``, in configuration files and on
the command line, without editing the package.

**Parameters.** A logic registered with ``config=Params`` (a frozen dataclass, as every
configuration here) is configured from plain data — ``logic_params:`` in a configuration file,
``logic_params=`` of the wrappers: :func:`make_logic` builds ``Params`` from the mapping with
:func:`~safeswitch.core.config.from_dict` (unknown keys and bad values refused by name) and
calls ``factory(context, params)``. A logic registered without one is called as
``factory(context)`` and refuses any parameter.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from typing import Any

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.core.switching import SwitchingError, SwitchingLogic, check_logic

#: The entry-point group third-party packages declare their logics in.
ENTRY_POINT_GROUP = "safeswitch.logics"

LogicFactory = Callable[..., SwitchingLogic[Any]]


@dataclass(frozen=True)
class LogicPlugin:
    """A registered switching logic.

    Attributes:
        factory: ``factory(context)``, or ``factory(context, params)`` with ``config``.
        config: The frozen dataclass of the logic's parameters (``None``: it takes none).
    """

    factory: LogicFactory
    config: type | None = None

    def __post_init__(self) -> None:
        if not callable(self.factory):
            raise ValueError(f"a logic factory must be callable, got {self.factory!r}")
        if self.config is not None and not (
            isinstance(self.config, type) and dataclasses.is_dataclass(self.config)
        ):
            raise ValueError(f"a logic's config must be a dataclass, got {self.config!r}")


_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_.-]*$")
_registered: dict[str, LogicPlugin] = {}
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


def register_logic(
    name: str, factory: LogicFactory, *, config: type | None = None, replace: bool = False
) -> None:
    """Make ``factory`` available as the switching logic ``name``.

    Args:
        name: Letters, digits, ``_``, ``.`` and ``-``, starting with a letter.
        factory: ``factory(context) -> SwitchingLogic`` (a logic class taking the context
            works too); with ``config``, ``factory(context, params)``.
        config: The frozen dataclass of the logic's parameters, so that it can be configured
            from a file (``logic_params:``); ``None``: the logic takes no parameters.
        replace: Allow replacing a logic registered under the same name.

    Raises:
        ValueError: A malformed name, a factory that is not callable, a config that is not a
            dataclass, or a name already taken (without ``replace``).
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
    _registered[name] = LogicPlugin(factory, config)


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


def logic_plugin(name: str) -> LogicPlugin:
    """The logic registered as ``name`` (a run-time registration wins over an entry point).

    Raises:
        UnknownLogicError: Naming the known logics.
    """
    if name in _registered:
        return _registered[name]
    entry = _discovered().get(name)
    if entry is None:
        known = ", ".join(logic_names()) or "none"
        raise UnknownLogicError(f"unknown switching logic {name!r}; known logics: {known}")
    loaded = entry.load()
    if not isinstance(loaded, LogicPlugin) and not callable(loaded):
        raise SwitchingError(
            f"entry point {name!r} of group {ENTRY_POINT_GROUP!r} ({entry.value}) is neither "
            "a LogicPlugin nor callable"
        )
    plugin = loaded if isinstance(loaded, LogicPlugin) else LogicPlugin(loaded)
    _registered[name] = plugin
    return plugin


def logic_factory(name: str) -> LogicFactory:
    """The factory registered as ``name`` (see :func:`logic_plugin`)."""
    return logic_plugin(name).factory


def logic_params(name: str, data: Mapping[str, Any] | None, where: str = "logic_params") -> Any:
    """The parameters of logic ``name`` built from plain data: an instance of its registered
    config class (its defaults where ``data`` is silent), or ``None`` for a logic that takes
    none.

    Raises:
        UnknownLogicError: No such logic.
        ConfigError: An unknown key or a bad value, or parameters for a logic that takes none
            (the message names the key and the logic).
    """
    plugin = logic_plugin(name)
    if plugin.config is None:
        if data:
            raise ConfigError(
                f"{where}: the switching logic {name!r} takes no parameters, got "
                f"{', '.join(map(repr, data))}"
            )
        return None
    return from_dict(plugin.config, data, where)


def make_logic(
    name: str, context: Any, params: Mapping[str, Any] | None = None
) -> SwitchingLogic[Any]:
    """The logic ``name`` built for ``context``, checked against the protocol.

    Args:
        name: A registered logic.
        context: The plant it is to supervise.
        params: Its parameters as plain data (see :func:`logic_params`).

    Raises:
        UnknownLogicError: No such logic.
        ConfigError: Bad parameters (named).
        LogicContextError: The logic does not serve this kind of plant.
        SwitchingError: The factory's result is not a valid switching logic.
    """
    plugin = logic_plugin(name)
    built = logic_params(name, params)
    logic = plugin.factory(context) if plugin.config is None else plugin.factory(context, built)
    check_logic(logic)
    return logic


def resolve_logic(
    logic: SwitchingLogic[Any] | str, context: Any, params: Mapping[str, Any] | None = None
) -> SwitchingLogic[Any]:
    """A logic object as given (checked), or the registered logic of that name built with
    ``params``.

    Raises:
        SwitchingError: ``params`` given with a logic object (they configure a registered one).
    """
    if isinstance(logic, str):
        return make_logic(logic, context, params)
    if params:
        raise SwitchingError(
            "logic_params configure a registered logic by name; the logic given is an object "
            f"({type(logic).__name__}): build it with its parameters instead"
        )
    check_logic(logic)
    return logic


#: The ``info`` keys whose truth on an episode's last step marks a failure, for a plant that
#: declares none (a driving plant's collision under the names highway-env and we use).
DEFAULT_FAILURE_KEYS = ("crashed", "collision")

#: How an episode's failure is read: an ``info`` key (a failure where the last step's value is
#: true) or ``failure(info) -> bool``.
Failure = str | Callable[[Mapping[str, Any]], bool]


def failure_check(failure: Failure | None) -> Callable[[Mapping[str, Any]], bool]:
    """``failure`` (see :data:`Failure`; ``None``: :data:`DEFAULT_FAILURE_KEYS`) as a
    predicate on an episode's last ``info``.

    Raises:
        ValueError: ``failure`` is neither a non-empty string nor callable (named).
    """
    if failure is None:
        return lambda info: any(bool(info.get(key, False)) for key in DEFAULT_FAILURE_KEYS)
    if isinstance(failure, str) and failure:
        return lambda info: bool(info.get(failure, False))
    if callable(failure):
        return lambda info: bool(failure(info))
    raise ValueError(f"failure must be an info key or callable(info) -> bool, got {failure!r}")


@dataclass(frozen=True)
class RegisteredController:
    """A Safety controller registered for a Gymnasium id.

    Attributes:
        factory: ``factory(env) -> safety_controller`` (``safety_controller(state) -> [B, A]``).
        state_fn: ``state_fn(env) -> state`` for :class:`~safeswitch.core.wrappers.SafeSwitch`
            (``None``: the last observation).
        failure: How the plant's failures are read (:data:`Failure`; ``None``:
            :data:`DEFAULT_FAILURE_KEYS`).
    """

    factory: Callable[[Any], Callable[[Any], Any]]
    state_fn: Callable[[Any], Any] | None = None
    failure: Failure | None = None


_controllers: dict[str, RegisteredController] = {}

#: The entry-point group through which an installed package registers Safety controllers:
#: each entry point names a callable that calls :func:`register_safety_controller`.
CONTROLLER_ENTRY_POINTS = "safeswitch.safety_controllers"


def register_safety_controller(
    env_id: str,
    factory: Callable[[Any], Callable[[Any], Any]],
    *,
    state_fn: Callable[[Any], Any] | None = None,
    failure: Failure | None = None,
) -> None:
    """Register the Safety controller of the environments ``env_id``, so that ``safeswitch
    train --env ENV_ID --switching LOGIC`` can wrap them in
    :class:`~safeswitch.core.wrappers.SafeSwitch`.

    Args:
        env_id: A Gymnasium id.
        factory: ``factory(env) -> safety_controller``.
        state_fn: What the controller and the logic see (default: the last observation).
        failure: What counts as the plant's failure: an ``info`` key, true on an episode's
            last step (e.g. ``"fell"``), or ``failure(info) -> bool`` (default: ``crashed`` or
            ``collision``). Training and evaluation count ``failures`` with it.

    Raises:
        ValueError: ``factory`` is not callable, or ``failure`` is neither a key nor callable.
    """
    if not callable(factory):
        raise ValueError(f"the Safety controller factory of {env_id!r} is not callable")
    failure_check(failure)  # refuses a malformed one now, not at the end of a run
    _controllers[env_id] = RegisteredController(factory, state_fn, failure)


def safety_controller_for(env_id: str) -> RegisteredController | None:
    """The Safety controller registered for ``env_id``, if any (those of installed packages'
    :data:`CONTROLLER_ENTRY_POINTS` loaded on first use)."""
    _load_controller_entry_points()
    return _controllers.get(env_id)


def failure_of(env_id: str) -> Callable[[Mapping[str, Any]], bool]:
    """The failure predicate of ``env_id``'s registered Safety controller (the default keys
    where none is registered or it declares none)."""
    registered = safety_controller_for(env_id)
    return failure_check(registered.failure if registered is not None else None)


def import_modules(names: Sequence[str]) -> None:
    """Import the user's modules (``--import``): what they register — environments, Safety
    controllers, switching logics — is known from then on.

    Raises:
        ModuleNotFoundError: A module that cannot be found (named).
    """
    for name in names:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                raise ModuleNotFoundError(
                    f"cannot import {name!r}: no module named {exc.name!r} (is it installed, "
                    "or its folder on PYTHONPATH?)"
                ) from exc
            raise


def plain_env_id(env_id: str) -> str:
    """``env_id`` without Gymnasium's ``module:`` prefix, the module imported first (so that
    ``mypackage.envs:Plant-v0`` registers ``Plant-v0``, as ``gymnasium.make`` does)."""
    module, sep, name = env_id.rpartition(":")
    if sep and module:
        import_modules([module])
        return name
    return env_id


_ENTRY_POINTS_LOADED: list[bool] = []


def _load_controller_entry_points() -> None:
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED.append(True)
    for entry in metadata.entry_points(group=CONTROLLER_ENTRY_POINTS):
        try:
            entry.load()()
        except Exception as exc:  # named, so that the user knows which package to fix
            raise SwitchingError(
                f"the Safety controller entry point {entry.name!r} ({entry.value}) failed: {exc}"
            ) from exc
