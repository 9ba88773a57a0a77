import math

import numpy as np
import pytest

from safeswitch.sim.params import IntersectionGeometry
from safeswitch.sim.road import LEG_DIRECTIONS, Intersection


@pytest.fixture(scope="module")
def intersection():
    return Intersection()


def total_turn(route):
    return math.degrees(np.unwrap(route.heading)[-1] - np.unwrap(route.heading)[0])


def test_astar_route_south_to_west_is_the_continuous_left_turn(intersection):
    g = intersection.geometry
    route = intersection.route("south", "west")
    # Starts on the south leg's incoming (northbound, east) lane, ends on the west leg's
    # outgoing (westbound, north) lane.
    np.testing.assert_allclose(
        route.points[0], [g.lane_width / 2, -(g.box_half_size + g.approach_length)]
    )
    assert route.points[-1, 1] == pytest.approx(g.lane_width / 2)
    assert route.points[-1, 0] < -g.box_half_size
    assert total_turn(route) == pytest.approx(90.0, abs=0.5)  # a left turn
    steps = np.linalg.norm(np.diff(route.points, axis=0), axis=1)
    assert steps.max() <= 1.0 and steps.min() > 0.49  # continuous, dense
    radius = g.box_half_size + g.lane_width / 2
    assert route.curvature.max() == pytest.approx(1 / radius, rel=0.01)
    expected = 2 * g.approach_length + math.pi / 2 * radius
    assert route.length == pytest.approx(expected, abs=g.waypoint_spacing)


@pytest.mark.parametrize(
    ("origin", "destination", "turn"),
    [
        ("north", "south", 0.0),
        ("south", "east", -90.0),
        ("east", "south", 90.0),
        ("west", "east", 0.0),
        ("east", "north", -90.0),
        ("north", "east", 90.0),
    ],
)
def test_every_route_turns_the_right_way(intersection, origin, destination, turn):
    assert total_turn(intersection.route(origin, destination)) == pytest.approx(turn, abs=0.5)


def test_lane_graph_has_no_u_turns(intersection):
    graph = intersection.lane_graph
    for leg in LEG_DIRECTIONS:
        assert not graph.has_edge((leg, "in", "end"), (leg, "out", "start"))


def test_unknown_leg_and_bad_geometry_are_named(intersection):
    with pytest.raises(ValueError, match="'up'"):
        intersection.route("up", "west")
    with pytest.raises(ValueError, match="box_half_size"):
        IntersectionGeometry(box_half_size=1.0)
    with pytest.raises(ValueError, match="waypoint_spacing"):
        IntersectionGeometry(waypoint_spacing=2.0)
