"""Batched PID controllers (paper Eq. 1) with output clamping and anti-windup.

The controller is a pure function over arrays so that one code path serves a batch of 1 and a
batch of 10,000: the caller owns the state (:class:`PIDState`) and passes it back every tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import flat, jit
from safeswitch.core.pid_gains import PIDGains, PIDKernel

FloatArray = NDArray[np.float64]


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
    shape = state.integral.shape
    error = flat(error, shape)
    out, integral, derivative = np.empty(shape), np.empty(shape), np.empty(shape)
    _pid_loop(
        gains.kernel,
        dt,
        error,
        flat(state.integral, shape),
        flat(state.prev_error, shape),
        flat(state.derivative, shape),
        out.reshape(-1),
        integral.reshape(-1),
        derivative.reshape(-1),
    )
    return out, PIDState(integral, error.reshape(shape), derivative)


@jit
def _pid_loop(
    gains: PIDKernel,
    dt: float,
    error: FloatArray,
    integral: FloatArray,
    prev_error: FloatArray,
    derivative: FloatArray,
    out: FloatArray,
    new_integral: FloatArray,
    new_derivative: FloatArray,
) -> None:
    """:func:`pid_step`, element by element."""
    for i in range(error.shape[0]):
        out[i], new_integral[i], new_derivative[i] = pid_tick(
            gains, dt, error[i], integral[i], prev_error[i], derivative[i]
        )


@jit
def pid_tick(
    gains: PIDKernel,
    dt: float,
    error: float,
    integral: float,
    prev_error: float,
    derivative: float,
) -> tuple[float, float, float]:
    """One PID (see :func:`pid_step`) for one element; ``gains`` is :attr:`PIDGains.kernel`.
    Returns the clamped output, the new integral and the new (filtered) derivative."""
    kp, ki, kd = gains.kp, gains.ki, gains.kd
    out_min, out_max, filter_s = gains.out_min, gains.out_max, gains.derivative_filter_s
    raw = 0.0 if math.isnan(prev_error) else (error - prev_error) / dt
    d = raw
    if filter_s > 0:
        d = derivative + dt / (filter_s + dt) * (raw - derivative)
    candidate = integral + error * dt
    unclamped = kp * error + ki * candidate + kd * d
    winding_up = (unclamped > out_max and error > 0) or (unclamped < out_min and error < 0)
    kept = integral if winding_up else candidate
    output = kp * error + ki * kept + kd * d
    return min(max(output, out_min), out_max), kept, d
