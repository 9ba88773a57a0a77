"""Batched PID controllers (paper Eq. 1) with output clamping and anti-windup.

The controller is a pure function over arrays so that one code path serves a batch of 1 and a
batch of 10,000: the caller owns the state (:class:`PIDState`) and passes it back every tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import clamp

FloatArray = NDArray[np.float64]


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


@dataclass
class PIDState:
    """Per-element memory of a batched PID.

    Attributes:
        integral: Integral of the error, shape ``[...]``.
        prev_error: Error of the previous tick, NaN before the first tick (no derivative kick).
        derivative: The (filtered) derivative of the error of the previous tick.
    """

    integral: FloatArray
    prev_error: FloatArray
    derivative: FloatArray

    @classmethod
    def zeros(cls, shape: tuple[int, ...], integral: float = 0.0) -> PIDState:
        """A fresh state for a batch of the given shape."""
        return cls(np.full(shape, float(integral)), np.full(shape, np.nan), np.zeros(shape))

    def copy(self) -> PIDState:
        return PIDState(self.integral.copy(), self.prev_error.copy(), self.derivative.copy())

    def reset_where(self, mask: NDArray[np.bool_], integral: float | FloatArray = 0.0) -> None:
        """Reset the elements selected by ``mask`` in place."""
        self.integral[mask] = np.broadcast_to(integral, self.integral.shape)[mask]
        self.prev_error[mask] = np.nan
        self.derivative[mask] = 0.0


def pid_step(
    gains: PIDGains, state: PIDState, error: FloatArray, dt: float
) -> tuple[FloatArray, PIDState]:
    """One tick of a batched PID: ``u = kp·e + ki·∫e dt + kd·de/dt``, clamped to the bounds.

    Anti-windup by conditional integration: the integral does not grow while the output is
    saturated and the error pushes it further into saturation. That way a controller that ran
    saturated for a long time (the Safety controller waits in parallel for its turn) responds at
    once when the error changes sign, instead of first unwinding a huge integral.

    Args:
        gains: Gains and output bounds.
        state: State of the previous tick (not modified).
        error: Error of this tick, any shape broadcastable to the state's.
        dt: Tick length [s].

    Returns:
        The clamped output and the new state.
    """
    error = np.asarray(error, dtype=np.float64)
    raw = np.where(np.isnan(state.prev_error), 0.0, (error - state.prev_error) / dt)
    if gains.derivative_filter_s > 0:
        alpha = dt / (gains.derivative_filter_s + dt)
        derivative = state.derivative + alpha * (raw - state.derivative)
    else:
        derivative = raw
    integral_candidate = state.integral + error * dt
    unclamped = gains.kp * error + gains.ki * integral_candidate + gains.kd * derivative
    winding_up = ((unclamped > gains.out_max) & (error > 0)) | (
        (unclamped < gains.out_min) & (error < 0)
    )
    integral = np.where(winding_up, state.integral, integral_candidate)
    output = gains.kp * error + gains.ki * integral + gains.kd * derivative
    return clamp(output, gains.out_min, gains.out_max), PIDState(integral, error, derivative)
