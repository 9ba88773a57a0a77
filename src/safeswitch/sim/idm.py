"""The Intelligent Driver Model (Treiber, Hennecke & Helbing, *Congested traffic states in
empirical observations and microscopic simulations*, Phys. Rev. E 62, 2000): the car-following
acceleration of the other vehicles in traffic.

    a = a_max · [1 − (v / v0)^δ − (s* / s)²],   s* = s0 + v·T + v·Δv / (2·√(a_max·b))

with ``s`` the bumper-to-bumper gap to the leader and ``Δv = v − v_leader``. Parameters after
Treiber & Kesting, *Traffic Flow Dynamics* (Springer, 2013), Table 11.2, city traffic:
T 1.0 s … 1.5 s, s0 2 m, a 1.0 … 1.5 m/s², b 1.5 … 2.0 m/s², δ 4. The model brakes harder than
``b`` when it must (the interaction term is unbounded); the result is clipped at the tyres'
limit ``max_brake``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from safeswitch.core.arrays import jit


@dataclass(frozen=True)
class IDMParams:
    """Parameters of the Intelligent Driver Model (defaults: Treiber & Kesting, city).

    Attributes:
        max_accel: ``a`` [m/s²].
        comfortable_decel: ``b`` [m/s²].
        time_headway: ``T`` [s].
        min_gap: ``s0`` [m].
        exponent: ``δ``.
        max_brake: Hardest braking the vehicle can do [m/s²].
    """

    max_accel: float = 1.5
    comfortable_decel: float = 2.0
    time_headway: float = 1.5
    min_gap: float = 2.0
    exponent: float = 4.0
    max_brake: float = 8.0

    def __post_init__(self) -> None:
        for name in ("max_accel", "comfortable_decel", "time_headway", "exponent", "max_brake"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"IDMParams.{name} must be > 0, got {value!r}")
        if not (math.isfinite(self.min_gap) and self.min_gap >= 0):
            raise ValueError(f"IDMParams.min_gap must be >= 0, got {self.min_gap!r}")

    @property
    def kernel(self) -> IDMKernel:
        return IDMKernel(
            self.max_accel, self.comfortable_decel, self.time_headway, self.min_gap,
            self.exponent, self.max_brake,
        )  # fmt: skip


class IDMKernel(NamedTuple):
    """:class:`IDMParams` as compiled code reads them."""

    max_accel: float
    comfortable_decel: float
    time_headway: float
    min_gap: float
    exponent: float
    max_brake: float


@jit
def idm_accel(speed: float, desired: float, gap: float, leader_speed: float, p: IDMKernel) -> float:
    """IDM acceleration [m/s²] for ``speed`` and ``desired`` speed [m/s], the gap to the leader
    [m] (``inf``: free road) and its speed [m/s], clipped to ``[-max_brake, max_accel]``."""
    ratio = max(speed, 0.0) / max(desired, 0.1)
    if p.exponent == 4.0:  # the usual δ, without a call to pow
        ratio *= ratio
        free = 1.0 - ratio * ratio
    else:
        free = 1.0 - ratio**p.exponent
    if math.isinf(gap):
        return min(max(p.max_accel * free, -p.max_brake), p.max_accel)
    wanted = (
        p.min_gap
        + speed * p.time_headway
        + speed * (speed - leader_speed) / (2.0 * math.sqrt(p.max_accel * p.comfortable_decel))
    )
    wanted = max(wanted, 0.0)
    a = p.max_accel * (free - (wanted / max(gap, 0.05)) ** 2)
    return min(max(a, -p.max_brake), p.max_accel)
