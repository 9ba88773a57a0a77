"""Switching logics as plugins: run-time registration and the ``safeswitch.logics`` entry
points of an installed distribution."""

import sys
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest

import safeswitch
from safeswitch import Decision
from safeswitch.core.config import ConfigError
from safeswitch.core.registry import (
    LogicContextError,
    UnknownLogicError,
    logic_names,
    make_logic,
    refresh_entry_points,
    register_logic,
    resolve_logic,
    unregister_logic,
)
from safeswitch.core.switching import NeverSwitch, SwitchingError
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask

PLUGIN = '''
import numpy as np
from safeswitch import Decision

CREATED = []


class BrakeBelowTwoMetres:
    """Brakes whenever the ego is within 2 m of its conflict-zone entry (a toy plugin)."""

    reasons = ("learned", "near_zone")

    def decide(self, state, learned, safe):
        near = np.abs(state.ego_to_stop) < 2.0
        return Decision(near, near.astype(np.int8), safe)


def make(task):
    CREATED.append(type(task).__name__)
    return BrakeBelowTwoMetres()
'''


@pytest.fixture
def installed_plugin(tmp_path, monkeypatch):
    """A distribution ``toyplugin`` on sys.path that declares the logic ``toy-brake``."""
    (tmp_path / "toyplugin.py").write_text(PLUGIN)
    info = tmp_path / "toyplugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toyplugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[safeswitch.logics]\ntoy-brake = toyplugin:make\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    refresh_entry_points()
    yield sys.modules.get("toyplugin")
    sys.modules.pop("toyplugin", None)
    refresh_entry_points()


def test_a_logic_declared_by_an_installed_package_is_usable_by_name(installed_plugin):
    assert "toy-brake" in logic_names()
    env = gym.make(safeswitch.ENV_ID, switching="toy-brake", scenario="yield2")
    env.reset(seed=0)
    reasons = set()
    for _ in range(400):
        *_, info = env.step(np.array([1.0], dtype=np.float32))
        reasons.add(info["reason"])
    import toyplugin

    assert toyplugin.CREATED == ["LeftTurnTask"]  # the factory got the task as its context
    assert reasons >= {"learned", "near_zone"}


def test_the_builtin_logics_are_entry_points_like_any_plugin():
    from importlib import metadata

    declared = {ep.name for ep in metadata.entry_points(group="safeswitch.logics")}
    assert {"paper", "certified", "none"} <= declared
    assert isinstance(make_logic("none", object()), NeverSwitch)


def test_run_time_registration_and_its_errors():
    register_logic("always-learned", lambda context: NeverSwitch())
    try:
        assert "always-learned" in logic_names()
        with pytest.raises(ValueError, match="already registered"):
            register_logic("always-learned", NeverSwitch)
        env = gym.make(safeswitch.ENV_ID, switching="always-learned")
        env.reset(seed=0)
        *_, info = env.step(np.array([np.nan], dtype=np.float32))
        # t = 0 is outside Algorithm 1's window: PID_th proposes, the NaN is not used
        assert info["reason"] == "rule_in_charge" and info["controller"] == "rule"
    finally:
        unregister_logic("always-learned")
    with pytest.raises(ValueError, match="must start with a letter"):
        register_logic("1bad name", NeverSwitch)
    with pytest.raises(ValueError, match="not callable"):
        register_logic("fine", 42)  # type: ignore[arg-type]
    with pytest.raises(UnknownLogicError, match=r"'nonesuch'.*known logics: .*certified"):
        make_logic("nonesuch", None)
    with pytest.raises(ConfigError, match="'nonesuch' is not a registered switching logic"):
        gym.make(safeswitch.ENV_ID, switching="nonesuch")


def test_a_logic_refuses_a_plant_it_was_not_written_for():
    with pytest.raises(LogicContextError, match="'paper' switching logic supervises the left"):
        make_logic("paper", object())

    class BadReasons:
        reasons = ("x",)

        def decide(self, state, learned, safe):
            raise AssertionError("never called")

    register_logic("bad-reasons", lambda context: BadReasons())
    try:
        with pytest.raises(SwitchingError, match="must start with 'learned'"):
            gym.make(safeswitch.ENV_ID, switching="bad-reasons")
    finally:
        unregister_logic("bad-reasons")


@dataclass(frozen=True)
class HoldParams:
    """Parameters of the toy logic below.

    Attributes:
        distance: Brake within this distance of the zone [m].
    """

    distance: float = 2.0

    def __post_init__(self):
        if not self.distance > 0:
            raise ConfigError(f"hold.distance must be > 0, got {self.distance!r}")


class HoldBefore:
    reasons = ("learned", "near_zone")

    def __init__(self, distance):
        self.distance = distance

    def decide(self, state, learned, safe):
        near = np.abs(state.ego_to_stop) < self.distance
        return Decision(near, near.astype(np.int8), safe)


@pytest.fixture
def configurable():
    register_logic("hold-before", lambda task, p: HoldBefore(p.distance), config=HoldParams)
    yield
    unregister_logic("hold-before")


def test_a_logic_registered_with_its_parameters_is_configured_from_plain_data(configurable):
    assert make_logic("hold-before", None).distance == 2.0  # its defaults
    assert make_logic("hold-before", None, {"distance": 5.0}).distance == 5.0
    # from a configuration file, as any other key of the left turn
    config = LeftTurnConfig.from_dict({"switching": "hold-before", "logic_params": {"distance": 7}})
    assert LeftTurnTask(config).switching.distance == 7.0
    with pytest.raises(
        ConfigError,
        match=r"unknown configuration key logic_params.'distanse' \(valid keys: distance\)",
    ):
        LeftTurnConfig.from_dict({"switching": "hold-before", "logic_params": {"distanse": 7}})
    with pytest.raises(ConfigError, match=r"logic_params\.distance: expected a number"):
        make_logic("hold-before", None, {"distance": "far"})
    with pytest.raises(ConfigError, match=r"hold\.distance must be > 0, got -1"):
        make_logic("hold-before", None, {"distance": -1.0})


def test_parameters_are_refused_where_no_logic_takes_them(configurable):
    with pytest.raises(ConfigError, match=r"'paper' takes no parameters, got 'ttr'"):
        LeftTurnConfig.from_dict({"switching": "paper", "logic_params": {"ttr": 3}})
    with pytest.raises(SwitchingError, match="configure a registered logic by name"):
        resolve_logic(NeverSwitch(), None, {"distance": 1.0})
    with pytest.raises(ValueError, match="must be a dataclass"):
        register_logic("x", NeverSwitch, config=dict)


def test_the_public_names_are_the_package_s_own():
    """SPEC's public interface: each name resolves on ``safeswitch`` itself, to the object its
    module defines (imported on first use), and ``__all__`` lists it."""
    from safeswitch.core import registry, switching, wrappers

    for name, module in (
        ("SafeSwitch", wrappers), ("SafeSwitchVecEnv", wrappers),
        ("SwitchingLogic", switching), ("Decision", switching),
        ("register_logic", registry), ("register_safety_controller", registry),
    ):  # fmt: skip
        assert getattr(safeswitch, name) is getattr(module, name), name
        assert name in safeswitch.__all__, name
    with pytest.raises(AttributeError, match="no attribute 'register_safety_controlers'"):
        safeswitch.register_safety_controlers  # noqa: B018
