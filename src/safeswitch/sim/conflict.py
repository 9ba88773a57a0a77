"""Where two routes conflict: the conflict point and each route's conflict zone.

Both are derived from the geometry, never typed in: the conflict point is where the two centre
lines cross; a route's conflict zone is the interval of arc length on which a car on it can
overlap (with a margin) a car anywhere on the other route.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from safeswitch.sim.collision import rectangle_separation
from safeswitch.sim.geometry import FloatArray, Route


@dataclass(frozen=True)
class ConflictGeometry:
    """Conflict point and zones of two routes, ``a`` and ``b``.

    Attributes:
        point: The crossing of the two centre lines [m], shape ``[2]``.
        s_point_a: Arc length of the conflict point along route ``a`` [m].
        s_point_b: Arc length of the conflict point along route ``b`` [m].
        zone_a: ``(enter, exit)`` arc lengths on route ``a`` between which a car on ``a`` can
            overlap a car on ``b`` [m].
        zone_b: The same for route ``b`` [m].
        margin: Clearance added around both footprints when the zones were computed [m].
    """

    point: FloatArray
    s_point_a: float
    s_point_b: float
    zone_a: tuple[float, float]
    zone_b: tuple[float, float]
    margin: float


def polyline_crossing(route_a: Route, route_b: Route) -> tuple[FloatArray, float, float]:
    """First crossing, along ``route_a``, of the two routes' polylines.

    Returns:
        The crossing point ``[2]`` and its arc length along each route [m].

    Raises:
        ValueError: If the routes do not cross.
    """
    a0, a1 = route_a.points[:-1, None, :], route_a.points[1:, None, :]
    b0, b1 = route_b.points[None, :-1, :], route_b.points[None, 1:, :]
    da, db, d0 = a1 - a0, b1 - b0, b0 - a0
    denom = da[..., 0] * db[..., 1] - da[..., 1] * db[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (d0[..., 0] * db[..., 1] - d0[..., 1] * db[..., 0]) / denom
        u = (d0[..., 0] * da[..., 1] - d0[..., 1] * da[..., 0]) / denom
    hits = (denom != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    if not hits.any():
        raise ValueError(f"routes {route_a.name!r} and {route_b.name!r} do not cross")
    i, j = np.argwhere(hits)[0]
    point = route_a.points[i] + t[i, j] * (route_a.points[i + 1] - route_a.points[i])
    return point, float((i + t[i, j]) * route_a.spacing), float((j + u[i, j]) * route_b.spacing)


def conflict_geometry(
    route_a: Route,
    route_b: Route,
    footprint_a: tuple[float, float],
    footprint_b: tuple[float, float],
    margin: float = 0.0,
    search_radius: float = 20.0,
) -> ConflictGeometry:
    """Conflict point and conflict zones of two crossing routes.

    Every waypoint pose of ``a`` (heading along the route) is tested against every waypoint pose
    of ``b`` within ``search_radius`` of the conflict point, with the separating-axis test.

    Args:
        route_a: First route.
        route_b: Second route.
        footprint_a: ``(length, width)`` of the car on ``a`` [m].
        footprint_b: ``(length, width)`` of the car on ``b`` [m].
        margin: Clearance added to each footprint's length and width [m].
        search_radius: Only waypoints this close to the conflict point are tested [m]; it must
            exceed half the longer car's diagonal plus the margin.

    Returns:
        The conflict geometry.
    """
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin!r}")
    point, s_a, s_b = polyline_crossing(route_a, route_b)
    near_a = np.flatnonzero(np.linalg.norm(route_a.points - point, axis=1) <= search_radius)
    near_b = np.flatnonzero(np.linalg.norm(route_b.points - point, axis=1) <= search_radius)
    yaw_a, yaw_b = route_a.heading[near_a], route_b.heading[near_b]
    gap = rectangle_separation(
        route_a.points[near_a][:, None, :],
        yaw_a[:, None],
        footprint_a[0] + margin,
        footprint_a[1] + margin,
        route_b.points[near_b][None, :, :],
        yaw_b[None, :],
        footprint_b[0] + margin,
        footprint_b[1] + margin,
    )
    overlap = gap <= 0.0
    rows, cols = near_a[overlap.any(axis=1)], near_b[overlap.any(axis=0)]
    # A zone that touches the searched window's edge would be cut short: refuse, loudly.
    for rows_or_cols, near, name in ((rows, near_a, route_a.name), (cols, near_b, route_b.name)):
        if rows_or_cols.min() == near.min() or rows_or_cols.max() == near.max():
            raise ValueError(
                f"conflict zone on {name!r} reaches the search radius {search_radius} m; "
                "increase search_radius"
            )
    return ConflictGeometry(
        point=point,
        s_point_a=s_a,
        s_point_b=s_b,
        zone_a=(float(rows.min() * route_a.spacing), float(rows.max() * route_a.spacing)),
        zone_b=(float(cols.min() * route_b.spacing), float(cols.max() * route_b.spacing)),
        margin=margin,
    )
