import math

import numpy as np
import pytest

from safeswitch.sim.geometry import (
    Route,
    RouteSet,
    heading_axes,
    pose,
    pose_axes,
    resample_polyline,
)
from safeswitch.sim.params import IntersectionGeometry
from safeswitch.sim.road import Intersection


def arc_route(radius=10.0, spacing=0.5):
    angles = np.linspace(0, math.pi / 2, 2000)
    pts = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return Route.from_polyline(pts, spacing, name="arc")


def test_resample_gives_exact_spacing_and_keeps_the_start():
    pts = resample_polyline(np.array([[0.0, 0.0], [10.2, 0.0]]), 0.5)
    np.testing.assert_allclose(np.diff(pts[:, 0]), 0.5)
    assert pts[0, 0] == 0.0 and pts[-1, 0] == pytest.approx(10.0)


def test_projection_on_a_straight_route():
    route = Route.from_polyline(np.array([[0.0, 0.0], [0.0, 50.0]]), 0.5)  # heading north
    s, lat, heading = route.project(np.array([[1.0, 12.3], [-2.0, 40.05]]))
    np.testing.assert_allclose(s, [12.3, 40.05])
    np.testing.assert_allclose(lat, [-1.0, 2.0])  # east of a northbound route is its right
    np.testing.assert_allclose(heading, math.pi / 2)


def test_projection_on_a_curve_matches_the_circle():
    route = arc_route(radius=10.0)
    angle = 0.6
    for r in (9.0, 10.0, 11.5):
        s, lat, heading = route.project(np.array([r * math.cos(angle), r * math.sin(angle)]))
        # s is measured along the waypoint polyline: off the arc it is exact only to about
        # |r - R|·(spacing / 2R), here 0.04 m.
        assert s == pytest.approx(10.0 * angle, abs=0.04)
        assert lat == pytest.approx(10.0 - r, abs=2e-3)  # inside the left turn is left
        assert heading == pytest.approx(angle + math.pi / 2, abs=0.03)


def test_windowed_projection_agrees_with_global_projection():
    route = arc_route()
    routes = RouteSet([route])
    rng = np.random.default_rng(1)
    s_true = rng.uniform(1, route.length - 1, 200)
    xy, _ = route.pose_at(s_true)
    xy += rng.normal(0, 0.5, xy.shape)
    idx = np.zeros(200, dtype=np.intp)
    local = routes.project(idx, xy, s_true + rng.uniform(-1, 1, 200))
    glob = routes.project_global(idx, xy)
    # Equal but where a point lies outside a polyline corner: there the walk measures the
    # distance to a segment's line and the global search the distance to the corner (< 1 mm).
    for a, b in zip(local, glob, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-3)


def test_curvature_and_arc_length_of_a_circle():
    route = arc_route(radius=10.0)
    np.testing.assert_allclose(route.curvature[5:-5], 0.1, rtol=1e-3)
    assert route.length == pytest.approx(10 * math.pi / 2, abs=0.5)
    assert route.arc_length_of(route.points[-1]) == pytest.approx(route.length, abs=1e-4)
    assert route.arc_length_of(np.array([10.0, 0.0])) == 0.0


def test_preview_offset_is_zero_on_a_straight_and_l2_over_2r_in_a_curve():
    straight = RouteSet([Route.from_polyline(np.array([[0.0, 0.0], [50.0, 0.0]]), 0.5)])
    zero = straight.preview_offset(
        np.array([0]), np.array([10.0]), np.array([[10.0, 0.0]]), np.array([0.0]), 5.0
    )
    assert zero[0] == pytest.approx(0.0, abs=1e-12)
    route = arc_route(radius=20.0)
    xy, yaw = route.pose_at(np.array([3.0]))
    offset = RouteSet([route]).preview_offset(np.array([0]), np.array([3.0]), xy, yaw, 5.0)
    angle = 5.0 / 20.0
    assert offset[0] == pytest.approx(20.0 * (1 - math.cos(angle)), rel=1e-3)  # ≈ l²/(2R)


def test_routes_with_different_spacing_are_refused():
    a = Route.from_polyline(np.array([[0.0, 0.0], [10.0, 0.0]]), 0.5, name="a")
    b = Route.from_polyline(np.array([[0.0, 0.0], [10.0, 0.0]]), 0.25, name="b")
    with pytest.raises(ValueError, match="spacing"):
        RouteSet([a, b])


def test_pose_axes_is_the_unit_vector_of_the_pose_heading():
    """Read from the table on straight segments or computed in curves: the same bits as
    ``math.cos``/``math.sin`` of :func:`pose`'s heading, everywhere on every route."""
    intersection = Intersection(IntersectionGeometry())
    routes = RouteSet([intersection.route(a, b) for a, b in (("south", "west"),
                                                               ("north", "south"),
                                                               ("east", "north"))])  # fmt: skip
    axes = heading_axes(routes.tables)
    k_max = routes.size - 2
    straight = curved = 0
    for r in range(len(routes.routes)):
        base = r * routes.size
        for s in np.linspace(-1.0, routes.lengths[r] + 2.0, 1501):
            x, y, heading = pose(routes.tables, routes.spacing, k_max, base, s)
            px, py, c, sn = pose_axes(routes.tables, axes, routes.spacing, k_max, base, s)
            assert (px, py) == (x, y)
            assert (c, sn) == (math.cos(heading), math.sin(heading))
            i = base + min(max(math.floor(s / routes.spacing), 0), k_max)
            if routes.tables[4, i + 1] == routes.tables[4, i]:
                straight += 1
            else:
                curved += 1
    assert straight > 0 and curved > 0  # both ways were taken
