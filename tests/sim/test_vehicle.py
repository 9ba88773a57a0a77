import math
from dataclasses import fields, replace

import numpy as np
import pytest

from safeswitch.sim.vehicle import (
    VehicleParams,
    VehicleState,
    longitudinal_force,
    steady_state_throttle,
    vehicle_step,
)

DT = 0.02
# A car with no resistance at all: what remains is pure kinematics.
FRICTIONLESS = replace(
    VehicleParams(),
    rolling_resistance=0.0,
    drag_area=0.0,
    engine_brake_coefficient=0.0,
    max_engine_brake_force=0.0,
)


def make_state(n=1, speed=0.0, yaw=0.0):
    return VehicleState.at(np.zeros(n), 0.0, yaw, speed)


def drive(params, state, throttle, brake, steer, ticks):
    outputs = []
    for _ in range(ticks):
        state, out = vehicle_step(params, state, throttle, brake, steer, DT)
        outputs.append(out)
    return state, outputs


def test_constant_speed_covers_v_times_t():
    state, _ = drive(FRICTIONLESS, make_state(speed=7.0, yaw=0.3), 0.0, 0.0, 0.0, ticks=500)
    distance = math.hypot(state.x[0], state.y[0])
    assert distance == pytest.approx(7.0 * 500 * DT, rel=1e-12)
    assert state.speed[0] == pytest.approx(7.0, rel=1e-12)


@pytest.mark.parametrize(("v0", "brake"), [(7.0, 0.5), (10.0, 0.3), (5.0, 0.8)])
def test_braking_at_constant_deceleration_stops_in_v2_over_2a(v0, brake):
    params = FRICTIONLESS
    decel = brake * params.max_brake_force / params.mass
    state, _ = drive(params, make_state(speed=v0), 0.0, brake, 0.0, ticks=1000)
    assert state.speed[0] == 0.0
    # The brake actuator lag delays the full deceleration by about its time constant, which
    # lengthens the stop by at most v0·tau; the integration itself is exact.
    ideal = v0**2 / (2 * decel)
    assert ideal <= state.x[0] <= ideal + v0 * params.brake_time_constant + 1e-9


def test_coasting_car_slows_down_and_small_throttle_still_loses_speed():
    params = VehicleParams()
    for throttle in (0.0, 0.1):
        state = make_state(speed=25 / 3.6)
        state.throttle[:] = throttle
        speeds = [state.speed[0]]
        for _ in range(250):
            state, _ = vehicle_step(params, state, throttle, 0.0, 0.0, DT)
            speeds.append(state.speed[0])
        assert np.all(np.diff(speeds) < 0), f"throttle {throttle} should lose speed"


def test_steady_state_throttle_holds_speed():
    params = VehicleParams()
    for v in (3.0, 6.94, 9.7):
        throttle = steady_state_throttle(params, v)
        assert longitudinal_force(params, np.array(v), throttle, 0.0) == pytest.approx(0, abs=1e-6)


def test_drive_force_is_limited_by_power_and_traction():
    params = VehicleParams()
    traction = params.friction_coefficient * params.mass * 9.81 * params.driven_axle_load_fraction
    low = longitudinal_force(params, np.array(1.0), 1.0, 0.0)
    assert low <= min(params.max_drive_force, traction)
    fast = 40.0
    assert longitudinal_force(params, np.array(fast), 1.0, 0.0) <= params.max_power / fast


def test_no_reversing_and_standing_car_stays_put_when_braked():
    state, _ = drive(VehicleParams(), make_state(speed=0.0), 0.0, 1.0, 0.0, ticks=100)
    assert state.speed[0] == 0.0 and state.x[0] == 0.0


def test_constant_steer_drives_the_kinematic_circle_and_reports_lateral_acceleration():
    params = FRICTIONLESS
    state = make_state(speed=6.0)
    state.steer[:] = 0.3
    state, outputs = drive(params, state, 0.0, 0.0, 0.3, ticks=200)
    delta = 0.3 * params.max_steer_angle
    slip = math.atan(params.cg_to_rear_axle / params.wheelbase * math.tan(delta))
    radius = params.wheelbase / (math.tan(delta) * math.cos(slip))  # path radius of the CG
    assert outputs[-1].yaw_rate[0] == pytest.approx(6.0 / radius, rel=1e-9)
    assert outputs[-1].accel_lat[0] == pytest.approx(6.0**2 / radius, rel=1e-9)


def test_heading_stays_a_unit_vector_and_matches_the_integrated_yaw_rate():
    state = make_state(speed=9.0, yaw=2.5)
    state.steer[:] = -0.8
    total = 0.0
    for _ in range(3000):  # a minute of driving in circles
        state, out = vehicle_step(VehicleParams(), state, 0.2, 0.0, -0.8, DT)
        total += out.yaw_rate[0] * DT
    assert state.cos_yaw[0] ** 2 + state.sin_yaw[0] ** 2 == pytest.approx(1.0, abs=1e-12)
    expected = math.atan2(math.sin(2.5 + total), math.cos(2.5 + total))
    assert state.yaw[0] == pytest.approx(expected, abs=1e-8)


def test_commands_are_clipped_at_the_plant_input():
    a, _ = vehicle_step(VehicleParams(), make_state(speed=5.0), 7.0, -3.0, 9.0, DT)
    b, _ = vehicle_step(VehicleParams(), make_state(speed=5.0), 1.0, 0.0, 1.0, DT)
    np.testing.assert_array_equal(a.speed, b.speed)
    np.testing.assert_array_equal(a.steer, b.steer)


def test_a_batch_of_n_equals_n_batches_of_one():
    rng = np.random.default_rng(0)
    n = 16
    state = make_state(n)
    state.speed[:] = rng.uniform(0, 10, n)
    yaw = rng.uniform(-3, 3, n)
    state.cos_yaw[:], state.sin_yaw[:] = np.cos(yaw), np.sin(yaw)
    cmds = [rng.uniform(-0.2, 1.2, (30, n)) for _ in range(3)]
    batch = state.copy()
    for t in range(30):
        batch, _ = vehicle_step(VehicleParams(), batch, cmds[0][t], cmds[1][t], cmds[2][t], DT)
    for i in range(n):
        single = VehicleState(
            *(getattr(state, f.name)[i : i + 1].copy() for f in fields(VehicleState))
        )
        for t in range(30):
            single, _ = vehicle_step(
                VehicleParams(),
                single,
                cmds[0][t, i : i + 1],
                cmds[1][t, i : i + 1],
                cmds[2][t, i : i + 1],
                DT,
            )
        assert single.x[0] == batch.x[i] and single.y[0] == batch.y[i]
        assert single.speed[0] == batch.speed[i]


def test_invalid_parameters_name_the_field():
    with pytest.raises(ValueError, match="mass"):
        VehicleParams(mass=-5.0)
    with pytest.raises(ValueError, match="cg_to_rear_axle"):
        VehicleParams(cg_to_rear_axle=3.0)


def reference_step(p, s, throttle_cmd, brake_cmd, steer_cmd, dt):
    """The model written out in numpy, independently of the compiled loop: the equations of the
    module docstring with the exact trigonometry (no small-angle series)."""
    g, rho = 9.81, 1.2

    def lag(tau, old, cmd, lo, hi):
        return old + (1.0 - math.exp(-dt / tau)) * (np.clip(cmd, lo, hi) - old)

    throttle = lag(p.throttle_time_constant, s.throttle, throttle_cmd, 0.0, 1.0)
    brake = lag(p.brake_time_constant, s.brake, brake_cmd, 0.0, 1.0)
    steer = lag(p.steer_time_constant, s.steer, steer_cmd, -1.0, 1.0)
    traction = p.friction_coefficient * p.mass * g * p.driven_axle_load_fraction
    drive = np.minimum(
        np.minimum(p.max_drive_force, p.max_power / np.maximum(s.speed, 0.1)), traction
    )
    drag = np.minimum(
        p.engine_brake_base_force * np.minimum(s.speed, 1.0) + p.engine_brake_coefficient * s.speed,
        p.max_engine_brake_force,
    )
    resist = p.rolling_resistance * p.mass * g + 0.5 * rho * p.drag_area * s.speed**2
    grip = p.friction_coefficient * p.mass * g
    force = throttle * drive - (1 - throttle) * drag - brake * p.max_brake_force - resist
    speed = np.maximum(s.speed + np.clip(force, -grip, grip) / p.mass * dt, 0.0)
    mean = 0.5 * (s.speed + speed)
    delta = steer * p.max_steer_angle
    slip = np.arctan(p.cg_to_rear_axle / p.wheelbase * np.tan(delta))
    yaw_rate = mean * np.cos(slip) * np.tan(delta) / p.wheelbase
    # the friction circle: the turn gets what the pedals leave of μ·g
    accel, circle = (speed - s.speed) / dt, p.friction_coefficient * g
    left = np.sqrt(np.maximum(circle**2 - accel**2, 0.0))
    wanted = np.abs(mean * yaw_rate)
    yaw_rate = np.where(wanted > left, yaw_rate * left / np.maximum(wanted, 1e-300), yaw_rate)
    yaw = np.arctan2(s.sin_yaw, s.cos_yaw)
    course = yaw + 0.5 * yaw_rate * dt + slip
    x = s.x + mean * dt * np.cos(course)
    y = s.y + mean * dt * np.sin(course)
    return x, y, yaw + yaw_rate * dt, speed, throttle, brake, steer, mean * yaw_rate


def test_the_compiled_tick_follows_the_model_equations_on_random_states():
    rng = np.random.default_rng(11)
    n = 20_000
    p = VehicleParams()
    state = VehicleState.at(
        rng.uniform(-50, 50, n),
        rng.uniform(-50, 50, n),
        rng.uniform(-3, 3, n),
        rng.uniform(0, 15, n),
    )
    state.throttle[:] = rng.uniform(0, 1, n)
    state.brake[:] = rng.uniform(0, 1, n)
    state.steer[:] = rng.uniform(-1, 1, n)
    cmds = rng.uniform(-0.5, 1.5, (3, n))  # out of range on purpose: the plant clips
    new, out = vehicle_step(p, state, cmds[0], cmds[1], cmds[2], DT)
    x, y, yaw, speed, throttle, brake, steer, accel_lat = reference_step(p, state, *cmds, DT)
    np.testing.assert_allclose(new.speed, speed, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(new.throttle, throttle, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(new.brake, brake, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(new.steer, steer, rtol=1e-12, atol=1e-12)
    # The heading rotation uses a fifth-order series: 1e-11 m at these turn rates.
    np.testing.assert_allclose(new.x, x, atol=1e-9)
    np.testing.assert_allclose(new.y, y, atol=1e-9)
    np.testing.assert_allclose(
        np.arctan2(np.sin(new.yaw - yaw), np.cos(new.yaw - yaw)), 0, atol=1e-9
    )
    np.testing.assert_allclose(out.accel_lat, accel_lat, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out.accel_lon, (new.speed - state.speed) / DT, rtol=1e-12)
    slid = out.grip_demand > 1.0
    assert 0.05 < slid.mean() < 0.95  # random states reach beyond the circle and stay within it


def test_no_pedals_and_steering_take_the_car_beyond_the_friction_circle():
    """Whatever is asked of it, the car's combined acceleration stays within μ·g; asked for
    more cornering than the circle leaves, the tyres give only that (the car runs wide)."""
    rng = np.random.default_rng(12)
    n = 50_000
    p = VehicleParams()
    state = VehicleState.at(0.0, 0.0, rng.uniform(-3, 3, n), rng.uniform(0, 30, n))
    state.throttle[:], state.brake[:] = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    state.steer[:] = rng.uniform(-1, 1, n)
    circle = p.friction_coefficient * 9.81
    for _ in range(50):
        cmds = rng.uniform(-0.2, 1.2, (3, n))
        state, out = vehicle_step(p, state, cmds[0], cmds[1], 2 * cmds[2] - 1, DT)
        assert (np.hypot(out.accel_lon, out.accel_lat) <= circle * (1 + 1e-9)).all()
        slid = out.grip_demand > 1.0
        assert slid.any() and (np.hypot(out.accel_lon, out.accel_lat)[slid] > 0.99 * circle).all()


def test_too_fast_into_a_curve_the_car_runs_wide_of_it():
    """A constant steering angle that holds a 20 m circle at 10 m/s (5 m/s²) cannot hold it
    at 20 m/s (20 m/s² > μ·g): the car's path is wider, and its lateral acceleration μ·g."""
    p = VehicleParams()
    radius = 20.0
    tan_delta = p.wheelbase / radius / np.cos(np.arctan(p.cg_to_rear_axle / radius))
    steer = np.arctan(tan_delta) / p.max_steer_angle
    ends = []
    for speed in (10.0, 20.0):
        state = VehicleState.at(np.zeros(1), 0.0, 0.0, speed)
        state.steer[:] = steer
        state.throttle[:] = 0.3
        for _ in range(50):  # hold the speed with the throttle the car needs, roughly
            state, out = vehicle_step(p, state, state.throttle, 0.0, steer, DT)
            state.speed[:] = speed  # a constant-speed test of the lateral limit
        ends.append((float(np.abs(out.accel_lat[0])), float(np.abs(out.yaw_rate[0]))))
    circle = p.friction_coefficient * 9.81
    assert abs(ends[0][0] - 10.0**2 / radius) < 0.3  # within the circle: the kinematic turn
    assert circle - 0.05 < ends[1][0] <= circle  # beyond it: only what the tyres give
    assert ends[1][1] * 20.0 < 20.0**2 / radius  # the path's curvature falls: it runs wide
