import numpy as np
import pytest

from safeswitch.core.pid import PIDState, pid_step
from safeswitch.core.pid_gains import PIDGains

DT = 0.02


def test_proportional_only_is_gain_times_error_clamped():
    gains = PIDGains(kp=2.0, ki=0.0, kd=0.0, out_min=-1.0, out_max=1.0)
    u, _ = pid_step(gains, PIDState.zeros((3,)), np.array([0.1, 0.4, -5.0]), DT)
    np.testing.assert_allclose(u, [0.2, 0.8, -1.0])


def test_integral_and_derivative_match_hand_computation():
    gains = PIDGains(kp=0.0, ki=0.5, kd=0.1, out_min=-100.0, out_max=100.0)
    state = PIDState.zeros((1,))
    u1, state = pid_step(gains, state, np.array([1.0]), DT)
    # First tick: no derivative kick, integral = e·dt.
    np.testing.assert_allclose(u1, [0.5 * 1.0 * DT])
    u2, state = pid_step(gains, state, np.array([3.0]), DT)
    np.testing.assert_allclose(u2, [0.5 * (1.0 + 3.0) * DT + 0.1 * (3.0 - 1.0) / DT])


def test_anti_windup_recovers_at_once_when_error_changes_sign():
    gains = PIDGains(kp=0.3, ki=0.4, kd=0.0, out_min=0.0, out_max=1.0)
    state = PIDState.zeros((1,))
    for _ in range(500):  # 10 s saturated at the top
        u, state = pid_step(gains, state, np.array([5.0]), DT)
    assert u[0] == 1.0
    # The integral stopped where the output first saturated, not at 5·10·0.4 = 20.
    assert state.integral[0] * gains.ki < 1.0 + 1e-9
    u, state = pid_step(gains, state, np.array([-2.0]), DT)
    assert u[0] < 1.0 - 0.3 * 2.0 + 1e-9


def test_reset_where_only_touches_selected_elements():
    state = PIDState(np.array([1.0, 2.0]), np.array([0.5, 0.5]), np.array([3.0, 3.0]))
    state.reset_where(np.array([False, True]))
    np.testing.assert_array_equal(state.integral, [1.0, 0.0])
    np.testing.assert_array_equal(state.derivative, [3.0, 0.0])
    assert state.prev_error[0] == 0.5 and np.isnan(state.prev_error[1])


def test_derivative_filter_smooths_a_step_in_the_error():
    raw = PIDGains(kp=0.0, ki=0.0, kd=1.0, out_min=-1e9, out_max=1e9)
    filtered = PIDGains(kp=0.0, ki=0.0, kd=1.0, out_min=-1e9, out_max=1e9, derivative_filter_s=0.2)
    outputs = {}
    for name, gains in (("raw", raw), ("filtered", filtered)):
        state = PIDState.zeros((1,))
        _, state = pid_step(gains, state, np.array([0.0]), DT)
        u, state = pid_step(gains, state, np.array([1.0]), DT)
        outputs[name] = u[0]
    assert outputs["raw"] == pytest.approx(1.0 / DT)
    # First-order filter: alpha = dt / (tau + dt) of the raw derivative on the first tick.
    assert outputs["filtered"] == pytest.approx(DT / (0.2 + DT) * (1.0 / DT))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"kp": -1.0}, "kp"), ({"ki": float("nan")}, "ki"), ({"out_min": 2.0}, "out_min")],
)
def test_invalid_gains_name_the_bad_value(kwargs, name):
    args = {"kp": 1.0, "ki": 0.0, "kd": 0.0, "out_min": 0.0, "out_max": 1.0} | kwargs
    with pytest.raises(ValueError, match=name):
        PIDGains(**args)
