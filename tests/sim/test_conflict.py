import math

import numpy as np
import pytest

from safeswitch.sim.collision import rectangles_overlap
from safeswitch.sim.conflict import conflict_geometry
from safeswitch.sim.road import Intersection

FOOTPRINT = (4.9, 2.1)


@pytest.fixture(scope="module")
def routes():
    intersection = Intersection()
    return intersection, intersection.route("south", "west"), intersection.route("north", "south")


def test_conflict_point_lies_on_both_routes_and_matches_the_circle(routes):
    intersection, ego, north = routes
    geo = conflict_geometry(ego, north, FOOTPRINT, FOOTPRINT)
    g = intersection.geometry
    radius, centre = g.box_half_size + g.lane_width / 2, -g.box_half_size
    x = -g.lane_width / 2
    y = centre + math.sqrt(radius**2 - (x - centre) ** 2)
    # The polyline's chords lie up to R·(1 - cos(spacing/2R)) ≈ 3 mm inside the circle.
    np.testing.assert_allclose(geo.point, [x, y], atol=5e-3)
    for route, s in ((ego, geo.s_point_a), (north, geo.s_point_b)):
        s_proj, lat, _ = route.project(geo.point)
        assert abs(lat) < 1e-3
        assert s_proj == pytest.approx(s, abs=1e-3)


def test_zones_contain_the_conflict_point_and_are_tight(routes):
    _, ego, north = routes
    geo = conflict_geometry(ego, north, FOOTPRINT, FOOTPRINT)
    assert geo.zone_a[0] < geo.s_point_a < geo.zone_a[1]
    assert geo.zone_b[0] < geo.s_point_b < geo.zone_b[1]

    def ego_hits_any_north_pose(s_ego):
        xy, yaw = ego.pose_at(np.array(s_ego))
        s_n = np.arange(geo.zone_b[0] - 5, geo.zone_b[1] + 5, 0.05)
        nxy, nyaw = north.pose_at(s_n)
        return bool(rectangles_overlap(xy, yaw, *FOOTPRINT, nxy, nyaw, *FOOTPRINT).any())

    spacing = ego.spacing
    assert ego_hits_any_north_pose(geo.zone_a[0])
    assert not ego_hits_any_north_pose(geo.zone_a[0] - spacing)
    assert ego_hits_any_north_pose(geo.zone_a[1])
    assert not ego_hits_any_north_pose(geo.zone_a[1] + spacing)


def test_a_margin_widens_the_zones(routes):
    _, ego, north = routes
    tight = conflict_geometry(ego, north, FOOTPRINT, FOOTPRINT)
    wide = conflict_geometry(ego, north, FOOTPRINT, FOOTPRINT, margin=1.0)
    assert wide.zone_a[0] < tight.zone_a[0] and wide.zone_a[1] > tight.zone_a[1]
    assert wide.zone_b[0] < tight.zone_b[0] and wide.zone_b[1] > tight.zone_b[1]


def test_parallel_routes_do_not_cross(routes):
    intersection, _, north = routes
    with pytest.raises(ValueError, match="do not cross"):
        conflict_geometry(north, intersection.route("south", "north"), FOOTPRINT, FOOTPRINT)
