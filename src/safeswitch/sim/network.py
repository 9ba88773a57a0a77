"""Every movement through the intersection, and how each pair of them interacts.

The twelve routes (each leg's incoming lane to each other leg's outgoing lane) are stacked in
one :class:`~safeswitch.sim.geometry.RouteSet`. For every ordered pair of routes the network
knows, from the geometry alone:

* **shared segments** — where the two centre lines coincide (the common approach lane of two
  routes from the same leg, up to where they part inside the box; the common exit lane of two
  routes to the same leg, from where they meet): there a vehicle on one route follows a vehicle
  on the other like any leader, and ``s_b = s_a + offset`` maps one route's arc length onto the
  other's;
* **conflict zones** — elsewhere, the arc-length intervals on which vehicles on the two routes
  can overlap (footprints with a margin, separating-axis test on the waypoint poses inside the
  box): a crossing, or the merge before a shared exit lane. Pairs that only ever follow each
  other have none.

Right of way, as on a priority road (the north–south road here; the east–west road has give-way
signs): going straight or turning right on the main road has priority over turning left from it
across the oncoming lane, and both over the minor road. :func:`priority_rank` gives the rank
(lower goes first).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from safeswitch.sim.collision import rectangle_separation
from safeswitch.sim.geometry import FloatArray, Route, RouteSet

#: Legs of the main (priority) road.
from safeswitch.sim.params import IntersectionGeometry
from safeswitch.sim.road import LEG_DIRECTIONS, Intersection

#: Legs of the main (priority) road.
MAIN_ROAD = ("north", "south")
#: How far centre lines may be apart and still count as one lane [m].
SAME_LANE = 0.05


def turn_of(origin: str, destination: str) -> str:
    """``straight``, ``left`` or ``right`` (right-hand traffic)."""
    legs = list(LEG_DIRECTIONS)  # south, east, north, west: counter-clockwise
    step = (legs.index(destination) - legs.index(origin)) % 4
    return {2: "straight", 1: "right", 3: "left"}[step]


def priority_rank(origin: str, destination: str) -> int:
    """Right of way: 0 main road straight or right, 1 main road left, 2 minor road."""
    if origin not in MAIN_ROAD:
        return 2
    return 1 if turn_of(origin, destination) == "left" else 0


@dataclass(frozen=True)
class Movement:
    """One route through the intersection.

    Attributes:
        origin: Leg it comes from.
        destination: Leg it leaves by.
        route: Its waypoints.
        stop_line: Arc length of its stop line [m].
        box_exit: Arc length at which it leaves the box [m].
        rank: Its right of way (:func:`priority_rank`).
    """

    origin: str
    destination: str
    route: Route
    stop_line: float
    box_exit: float
    rank: int

    @property
    def name(self) -> str:
        return f"{self.origin}->{self.destination}"


class RoadNetwork:
    """The intersection's twelve movements and their pairwise relations (see the module
    docstring).

    Args:
        geometry: The intersection.
        footprint: ``(length, width)`` of a vehicle [m].
        margin: Clearance added to the footprints for the conflict zones [m].
    """

    def __init__(
        self,
        geometry: IntersectionGeometry | None = None,
        footprint: tuple[float, float] = (4.9, 2.1),
        margin: float = 0.3,
    ) -> None:
        self.intersection = Intersection(geometry)
        self.footprint = footprint
        self.margin = margin
        g = self.intersection.geometry
        movements = []
        for origin in LEG_DIRECTIONS:
            for destination in LEG_DIRECTIONS:
                if origin == destination:
                    continue
                route = self.intersection.route(origin, destination)
                inside = np.flatnonzero(self.intersection.contains(route.points))
                movements.append(
                    Movement(
                        origin, destination, route, g.approach_length,
                        float(inside.max() * route.spacing), priority_rank(origin, destination),
                    )
                )  # fmt: skip
        self.movements: tuple[Movement, ...] = tuple(movements)
        self.routes = RouteSet([m.route for m in movements])

    def index(self, origin: str, destination: str) -> int:
        """Index of a movement (and of its route in :attr:`routes`)."""
        for i, m in enumerate(self.movements):
            if (m.origin, m.destination) == (origin, destination):
                return i
        raise ValueError(f"no movement {origin}->{destination}")

    @cached_property
    def shared(self) -> FloatArray:
        """``[R, R, 2, 3]``: per ordered pair, up to two shared segments ``(lo, hi, offset)``
        on the first route (``s_second = s_first + offset``); ``lo > hi`` marks none. Slot 0:
        the whole route for a route with itself; else a common start (same origin) — the
        approach lane and the first metres of the box, until the centre lines are a car's
        width apart; slot 1: a common end (same destination) — the exit lane from where the
        two join it."""
        n = len(self.movements)
        out = np.zeros((n, n, 2, 3))
        out[..., 0], out[..., 1] = 1.0, -1.0
        apart = self.footprint[1] + self.margin
        graph = self.intersection.lane_graph
        for i, a in enumerate(self.movements):
            for j, b in enumerate(self.movements):
                if i == j:  # one lane all along
                    out[i, j, 0] = (0.0, a.route.length + 50.0, 0.0)
                    continue
                if a.origin == b.origin:
                    pa, pb = a.route.points, b.route.points
                    k = min(len(pa), len(pb))
                    far = np.flatnonzero(np.linalg.norm(pa[:k] - pb[:k], axis=1) > apart)
                    out[i, j, 0] = (0.0, (far[0] if far.size else k) * a.route.spacing, 0.0)
                if a.destination == b.destination:
                    join = graph.nodes[(a.destination, "out", "start")]["pos"]
                    s_a, s_b = a.route.arc_length_of(join), b.route.arc_length_of(join)
                    out[i, j, 1] = (s_a, a.route.length + 50.0, s_b - s_a)
        return out

    @cached_property
    def conflicts(self) -> FloatArray:
        """``[R, R, 2]``: per ordered pair, the conflict zone ``(enter, exit)`` on the first
        route [m] — the arc lengths, inside the box and a car length around it, on which a
        vehicle on it can overlap one on the other route; NaN where they cannot (parallel
        lanes) or only follow each other (same origin)."""
        n = len(self.movements)
        out = np.full((n, n, 2), np.nan)
        length, width = (x + self.margin for x in self.footprint)
        box = self.intersection.geometry.box_half_size + length
        for i, a in enumerate(self.movements):
            near_a = np.flatnonzero(np.abs(a.route.points).max(axis=1) <= box)
            for j, b in enumerate(self.movements):
                if j <= i or a.origin == b.origin:
                    continue
                near_b = np.flatnonzero(np.abs(b.route.points).max(axis=1) <= box)
                gap = rectangle_separation(
                    a.route.points[near_a][:, None, :], a.route.heading[near_a][:, None],
                    length, width,
                    b.route.points[near_b][None, :, :], b.route.heading[near_b][None, :],
                    length, width,
                )  # fmt: skip
                overlap = gap <= 0.0
                if not overlap.any():
                    continue
                rows, cols = near_a[overlap.any(axis=1)], near_b[overlap.any(axis=0)]
                out[i, j] = rows.min() * a.route.spacing, rows.max() * a.route.spacing
                out[j, i] = cols.min() * b.route.spacing, cols.max() * b.route.spacing
        return out

    @cached_property
    def ranks(self) -> np.ndarray:
        """Right of way of each movement ``[R]``."""
        return np.array([m.rank for m in self.movements], dtype=np.int64)

    @cached_property
    def stop_lines(self) -> FloatArray:
        return np.array([m.stop_line for m in self.movements])

    @cached_property
    def box_exits(self) -> FloatArray:
        return np.array([m.box_exit for m in self.movements])

    @cached_property
    def lengths(self) -> FloatArray:
        return np.array([m.route.length for m in self.movements])


def _common_prefix(a: FloatArray, b: FloatArray) -> int:
    """Number of leading waypoints two polylines share (within :data:`SAME_LANE`)."""
    n = min(len(a), len(b))
    apart = np.linalg.norm(a[:n] - b[:n], axis=1) > SAME_LANE
    return int(np.argmax(apart)) if apart.any() else n
