"""What perception errors do to the shipped controllers, and what the declared bounds cost.

Three controllers drive the same random scenarios while the ego sees the north car through a
sensor (:mod:`safeswitch.leftturn.perception`): the paper policy under the paper's logic, and the
certified policy under the certified logic taking what it sees as the truth (``perfect``, the
paper's Remark 2) or keeping its guarantee for the declared bounds (``declared``). Collisions,
failures and every other metric use the truth; efficiency is against the oracle, which plans on
the truth. The report's perception section and ``benchmarks/perception.py`` both run this.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

from safeswitch.app.evaluate import controller_setup, fit_observations, traffic_setup
from safeswitch.core.config import from_dict
from safeswitch.evaluation.evaluate import run_controller, scenario_set, summary_against_oracle
from safeswitch.evaluation.oracle import OraclePlan
from safeswitch.evaluation.rollout import Policy
from safeswitch.leftturn.config import LeftTurnConfig, PerceptionConfig, TrafficConfig
from safeswitch.leftturn.make import build_task


@dataclass(frozen=True)
class Controller:
    """One controller of the study.

    Attributes:
        name: Its name in tables and figures.
        model: The shipped policy.
        assume: The certified logic's ``perception`` (``None``: the paper's logic).
        traffic: A traffic preset (``None``: the paper's scene).
    """

    name: str
    model: str
    assume: Literal["declared", "perfect"] | None
    traffic: str | None = None


CONTROLLERS = (
    Controller("paper policy, paper logic", "paper", None),
    Controller("certified policy, certified assuming perfect perception", "certified", "perfect"),
    Controller("certified policy, certified with declared bounds", "certified", "declared"),
)

#: The same in traffic from every leg (the ``test`` family, the densest): the policies trained
#: there.
TRAFFIC_CONTROLLERS = (
    Controller("traffic-paper policy, paper logic", "traffic-paper", None, "test"),
    Controller("traffic-certified policy, certified assuming perfect perception",
               "traffic-certified", "perfect", "test"),
    Controller("traffic-certified policy, certified with declared bounds", "traffic-certified",
               "declared", "test"),
)  # fmt: skip

#: The bounds the issue names for the price of robustness, and each key's unit step of a sweep.
REFERENCE = {"position_error_m": 1.0, "speed_error_mps": 1.0, "latency_s": 0.2}

#: Keys whose summary a study row keeps.
KEPT = (
    "episodes", "failures", "collisions", "lost_control_episodes", "safety_activation_episodes",
    "cleared_episodes", "mean_efficiency", "speeding_episodes", "comfort_violation_fraction",
    "comfort_violation_episodes",
)  # fmt: skip


def _setup(controller: Controller) -> tuple[LeftTurnConfig, Policy, TrafficConfig | None]:
    config, policy = controller_setup("learned", controller.model, None)
    traffic, _ = traffic_setup("learned", controller.model, controller.traffic)
    assert policy is not None
    if controller.assume is not None:
        config = replace(
            config, switching="certified",
            certified=replace(config.certified, perception=controller.assume),
        )  # fmt: skip
    return config, policy, traffic


def study(
    settings: Sequence[tuple[str, float, dict[str, Any]]],
    episodes: int,
    seed: int,
    controllers: Sequence[Controller] = CONTROLLERS,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Every controller under every perception setting on the same ``episodes`` random
    scenarios drawn with ``seed``.

    Args:
        settings: ``(sweep, level, perception)`` per cell: the sweep's name (a key, or
            ``"together"``), its level on the x axis, and the perception block.
        episodes: Random scenarios per cell.
        seed: Their seed.
        controllers: Who drives.
        log: Progress lines.

    Returns:
        One row per controller and setting: the setting, the controller and the summary's
        :data:`KEPT` keys (the truth's).
    """
    rows = []
    for controller in controllers:
        config, policy, traffic = _setup(controller)
        base = build_task(None, config, traffic=traffic)
        batch, _ = scenario_set(base, "random", episodes, seed)
        fitted = fit_observations(policy, controller.model, base)
        assert fitted is not None
        plan: OraclePlan | None = None
        for sweep, level, perception in settings:
            block = from_dict(PerceptionConfig, perception, where="perception")
            task = build_task(None, replace(config, perception=block), traffic=traffic)
            result, plan = run_controller(task, fitted, batch, plan=plan, trace=False)
            summary = summary_against_oracle(result, plan, config.episode.horizon_s)
            rows.append({
                "controller": controller.name, "scene": controller.traffic or "paper's scene",
                "sweep": sweep, "level": level,
                "errors": block.errors, "perception": perception,
                **{k: summary[k] for k in KEPT},
            })  # fmt: skip
            if log is not None:
                log(f"  {controller.name:58s} {sweep:18s} {level:5g} {block.errors:11s} "
                    f"collisions {summary['collisions']:4d}  efficiency "
                    f"{summary['mean_efficiency']:.3f}")  # fmt: skip
    return rows


def together(level: float, errors: str) -> dict[str, Any]:
    """Every bounded error at ``level`` times :data:`REFERENCE` (0: perfect perception)."""
    if level == 0:
        return {}
    return {**{k: v * level for k, v in REFERENCE.items()}, "errors": errors}
