"""``safeswitch demo``: a short closed-loop run of the embedded simulator, printed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from safeswitch.core.pid import PIDGains, PIDState, pid_step
from safeswitch.sim import (
    AutopilotParams,
    Intersection,
    World,
    autopilot_pedals,
    conflict_geometry,
    preview_offsets,
)


def run_demo(out: str) -> int:
    """Ego cruises through the left turn under ``PID_th``/``PID_lka``; the north car passes."""
    intersection = Intersection()
    world = World([intersection.route("south", "west"), intersection.route("north", "south")])
    p = world.params
    geo = conflict_geometry(
        world.routes[0], world.routes[1], (p.length, p.width), (p.length, p.width)
    )
    v_lim, v_north = 25 / 3.6, 8.0
    state = world.place(
        np.array([[geo.s_point_a - 45.0, geo.s_point_b - 80.0]]), np.array([[v_lim, v_north]])
    )
    pid_th = PIDGains(1.5, 0.05, 0.002, 0.0, 0.7)
    pid_lka = PIDGains(0.2, 0.01, 0.020, -1.0, 1.0)
    th, lka, north = PIDState.zeros((1,)), PIDState.zeros((1, 2)), PIDState.zeros((1,))
    min_gap, max_dev, max_alat = np.inf, 0.0, 0.0
    for _ in range(int(15.0 / world.dt)):
        u, th = pid_step(pid_th, th, v_lim - state.vehicles.speed[:, 0], world.dt)
        steer, lka = pid_step(pid_lka, lka, preview_offsets(world, state, 5.0), world.dt)
        tn, bn, north = autopilot_pedals(
            AutopilotParams(), p, state.vehicles.speed[:, 1], np.array([v_north]), north, world.dt
        )
        state, outputs, gap = world.step(
            state, np.stack([u, tn], 1), np.stack([np.zeros(1), bn], 1), steer
        )
        min_gap = min(min_gap, float(gap[0]))
        max_dev = max(max_dev, float(abs(state.lateral[0, 0])))
        max_alat = max(max_alat, float(abs(outputs.accel_lat[0, 0])))
    summary = {
        "simulated_s": float(state.time[0]),
        "ego_progress_m": float(state.progress[0, 0]),
        "min_separation_m": min_gap,
        "collision": min_gap <= 0.0,
        "max_lateral_deviation_m": max_dev,
        "max_lateral_accel_mps2": max_alat,
        "conflict_point": geo.point.round(3).tolist(),
    }
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    tmp = path / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(path / "summary.json")
    for key, value in summary.items():
        print(f"{key:>26}: {value}")
    return 0
