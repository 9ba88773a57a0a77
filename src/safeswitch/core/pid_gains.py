"""The gains of a PID controller, as a configuration holds them and as compiled code reads
them."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple


@dataclass(frozen=True)
class PIDGains:
    """Gains and output bounds of one PID controller.

    Attributes:
        kp: Proportional gain [output unit / error unit].
        ki: Integral gain [output unit / (error unit · s)].
        kd: Derivative gain [output unit · s / error unit].
        out_min: Lower bound of the output.
        out_max: Upper bound of the output.
        derivative_filter_s: Time constant of a first-order low-pass filter on the derivative
            term [s]; 0 leaves it unfiltered. A derivative of a noisy or quickly changing
            measurement (a per-tick acceleration, say) otherwise makes the output chatter.
    """

    kp: float
    ki: float
    kd: float
    out_min: float
    out_max: float
    derivative_filter_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "out_min", "out_max", "derivative_filter_s"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"PIDGains.{name} must be finite, got {value!r}")
        for name in ("kp", "ki", "kd", "derivative_filter_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"PIDGains.{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.out_min < self.out_max:
            raise ValueError(
                f"PIDGains needs out_min < out_max, got out_min={self.out_min!r}, "
                f"out_max={self.out_max!r}"
            )

    @functools.cached_property
    def kernel(self) -> PIDKernel:
        """These gains as the compiled :func:`pid_tick` reads them."""
        return PIDKernel(
            self.kp, self.ki, self.kd, self.out_min, self.out_max, self.derivative_filter_s
        )


class PIDKernel(NamedTuple):
    """:class:`PIDGains` as compiled code reads them (field for field)."""

    kp: float
    ki: float
    kd: float
    out_min: float
    out_max: float
    derivative_filter_s: float
