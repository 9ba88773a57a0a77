"""``safeswitch/Highway-v0``: highway-env's highway with continuous actions under a switching
logic, with the Safety controller that logic reasons about (:mod:`safeswitch.examples.highway`
for the plant's state, ``ttc`` and its controller; :mod:`safeswitch.examples.highway_certified`
for ``certified``). highway-env is imported only when an environment is made."""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from safeswitch.core.wrappers import SafeSwitch
from safeswitch.examples.highway import (
    HIGHWAY_CONFIG,
    STEER_RANGE,
    VEHICLE_LENGTH,
    HighwaySafetyController,
    highway_rules,
    highway_state,
)
from safeswitch.examples.highway_certified import CertifiedHighwayController, certified_rules

#: Comfort limits on the ego's accelerations [m/s²] (the left turn's, SPEC: |a_lon| ≤ 5,
#: |a_lat| ≤ 3) and the margin above the lane's speed limit that counts as speeding [m/s]
#: (0.1 km/h, as for the left turn).
COMFORT_ACCEL_LON = 5.0
COMFORT_ACCEL_LAT = 3.0
SPEEDING_MARGIN = 0.1 / 3.6


#: The shortest time gap to the vehicle ahead that is not a ``following`` cost [s]: half the
#: "two-second rule" drivers are taught. The shipped ``highway-certified`` policy met the
#: ``certified`` logic's ``leader`` interventions at gaps of 0.65-0.85 s (its first 15
#: evaluation episodes; docs/highway.md).
FOLLOWING_GAP_S = 1.0


def time_gap(env: gym.Env[Any, Any]) -> float:
    """The time gap [s] from the ego's front bumper to the rear bumper of the vehicle ahead in
    its lane, at the ego's speed (``inf`` with none ahead or at a standstill, 0 when the two
    touch)."""
    road = env.unwrapped.road  # type: ignore[attr-defined]
    ego = env.unwrapped.vehicle  # type: ignore[attr-defined]
    front, _ = road.neighbour_vehicles(ego, ego.lane_index)
    if front is None:
        return math.inf
    lane = road.network.get_lane(ego.lane_index)
    gap = lane.local_coordinates(front.position)[0] - lane.local_coordinates(ego.position)[0]
    gap -= 0.5 * (ego.LENGTH + front.LENGTH)
    if gap <= 0:
        return 0.0
    return gap / ego.speed if ego.speed > 0 else math.inf


class HighwayCosts(gym.Wrapper[Any, Any, Any, Any]):
    """highway-env's plant with the driving rules it does not score: after every step
    ``info["costs"]`` holds ``speeding`` (1.0 when the ego is above its lane's speed limit —
    30 m/s on highway-env's highway — by more than :data:`SPEEDING_MARGIN`) and ``comfort``
    (1.0 when the step's longitudinal or lateral acceleration exceeds
    :data:`COMFORT_ACCEL_LON` / :data:`COMFORT_ACCEL_LAT`), and ``info["accel_lat"]`` the lateral
    acceleration [m/s²]. The accelerations are the ones highway-env's kinematic bicycle applied
    over the step: the commanded ``acceleration`` and ``v²·sin β / (L/2)`` for the steering
    angle δ (``β = atan(tan δ / 2)``, ``L`` the vehicle length), at the speed the step began
    with. ``following`` is 1.0 when the time gap to the vehicle ahead in the ego's lane is below
    :data:`FOLLOWING_GAP_S` (bumper to bumper, at the ego's speed). Each cost can be a training
    constraint by name (``constraints: {speeding: …}``)."""

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        ego = self.env.unwrapped.vehicle  # type: ignore[attr-defined]
        speed = float(ego.speed)
        obs, reward, terminated, truncated, info = self.env.step(action)
        beta = math.atan(0.5 * math.tan(float(ego.action["steering"])))
        accel_lat = speed * speed * math.sin(beta) / (0.5 * VEHICLE_LENGTH)
        accel_lon = float(ego.action["acceleration"])
        info["accel_lat"] = accel_lat
        info["time_gap"] = time_gap(self.env)
        info["costs"] = {
            **info.get("costs", {}),
            "speeding": float(ego.speed > ego.lane.speed_limit + SPEEDING_MARGIN),
            "comfort": float(
                abs(accel_lon) > COMFORT_ACCEL_LON or abs(accel_lat) > COMFORT_ACCEL_LAT
            ),
            "following": float(info["time_gap"] < FOLLOWING_GAP_S),
        }
        return obs, reward, terminated, truncated, info


class LearnedSteering(gym.Wrapper[Any, Any, Any, Any]):
    """The learned controller's steering range, outside the switch: the policy's steering
    ``s ∈ [-1, 1]`` reaches the switch as ``s · limit / (π/4)`` (highway-env maps ±1 to ±45°),
    so the policy can steer at most ``±limit`` rad while the Safety controller keeps the
    plant's full range and the logic reasons in the plant's units, as before. The actions in
    ``info`` (``learned_action``, ``executed_action``) are mapped back to the policy's units
    (clipped to ±1), so learning from the interventions fits what the policy can command."""

    def __init__(self, env: gym.Env[Any, Any], limit: float) -> None:
        super().__init__(env)
        if not 0 < limit <= STEER_RANGE:
            raise ValueError(f"steering_limit must lie in (0, {STEER_RANGE:.4f}] rad, got {limit}")
        self.scale = limit / STEER_RANGE

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        plant = np.array(action, dtype=np.float32, copy=True)
        plant[..., 1] = np.clip(plant[..., 1], -1.0, 1.0) * self.scale
        obs, reward, terminated, truncated, info = self.env.step(plant)
        for key in ("learned_action", "executed_action"):
            if key in info:
                mapped = np.array(info[key], dtype=np.float64, copy=True)
                mapped[..., 1] = np.clip(mapped[..., 1] / self.scale, -1.0, 1.0)
                info[key] = mapped
        return obs, reward, terminated, truncated, info


def make_highway_env(
    switching: str = "ttc",
    penalty: float = -1.0,
    config: dict[str, Any] | None = None,
    render_mode: str | None = None,
    logic_params: dict[str, Any] | None = None,
    steering_limit: float | None = None,
) -> gym.Env[Any, Any]:
    """``safeswitch/Highway-v0``: highway-env's ``highway-fast-v0`` with continuous actions
    under a switching logic.

    Args:
        switching: A registered logic (``certified``, ``ttc``, ``none`` or a plugin's);
            ``certified`` comes with the Safety controller it reasons about
            (:class:`~safeswitch.examples.highway_certified.CertifiedHighwayController`),
            every other with :class:`HighwaySafetyController`.
        penalty: ``R_ADAS`` on a step the Safety controller acted (ours: highway-env's
            normalised reward lies in [0, 1] per step, so -1 costs a step's worth of reward; the
            paper's -25 was set against a per-tick reward of up to 4).
        config: highway-env configuration entries that replace :data:`HIGHWAY_CONFIG`'s.
        render_mode: Passed to highway-env (``"rgb_array"`` for pictures).
        logic_params: Parameters of the logic (``ttc``: :class:`TTCParams`' keys).
        steering_limit: The learned controller's steering range [rad] (:class:`LearnedSteering`;
            ``None``: highway-env's ±π/4, which at 25 m/s turns ±0.02 of the action into
            ±2 m/s² of lateral acceleration).
    """
    import highway_env  # noqa: F401  (registers highway-fast-v0)

    env = HighwayCosts(
        gym.make(
            "highway-fast-v0",
            config={**HIGHWAY_CONFIG, **(config or {})},
            render_mode=render_mode,
        )
    )
    controller: Any = HighwaySafetyController(highway_rules(env))
    if switching == "certified":
        controller = CertifiedHighwayController(certified_rules(env))
    switched = SafeSwitch(
        env,
        controller,
        switching,
        penalty=penalty,
        state_fn=highway_state,
        logic_params=logic_params,
    )
    return switched if steering_limit is None else LearnedSteering(switched, steering_limit)


__all__ = ["FOLLOWING_GAP_S", "HighwayCosts", "LearnedSteering", "make_highway_env", "time_gap"]
