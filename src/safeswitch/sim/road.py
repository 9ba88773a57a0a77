"""A four-leg intersection with one lane each way per leg, its lane graph, and A* routes.

Coordinates: x east, y north, origin at the centre of the intersection; right-hand traffic.
Each leg has an incoming lane (towards the centre) and an outgoing lane. Inside the box,
connector lanes join every incoming lane to the outgoing lanes of the three other legs (left,
straight, right; no U-turns). Turns are circular arcs tangent to both lanes.

Routes are found the way CARLA's global route planner finds them: an A* search over the lane
graph (``networkx``), then the edges' geometry is joined and resampled to dense waypoints.
"""

from __future__ import annotations

import itertools
import math
from functools import cached_property

import networkx as nx
import numpy as np

from safeswitch.sim.geometry import FloatArray, Route
from safeswitch.sim.params import IntersectionGeometry

#: Unit vector pointing from the centre outwards along each leg.
LEG_DIRECTIONS: dict[str, tuple[float, float]] = {
    "south": (0.0, -1.0),
    "east": (1.0, 0.0),
    "north": (0.0, 1.0),
    "west": (-1.0, 0.0),
}


def _right_of(direction: FloatArray) -> FloatArray:
    """Unit vector to the right of a driving direction."""
    return np.array([direction[1], -direction[0]])


class Intersection:
    """The road network: lanes, connectors and the lane graph.

    Args:
        geometry: Dimensions of the intersection.
    """

    def __init__(self, geometry: IntersectionGeometry | None = None) -> None:
        self.geometry = geometry or IntersectionGeometry()

    def stop_line_point(self, leg: str) -> FloatArray:
        """Centre of the incoming lane of ``leg`` at its stop line [m]."""
        u = np.array(LEG_DIRECTIONS[leg])
        return u * self.geometry.box_half_size + _right_of(-u) * self.geometry.lane_width / 2

    def _lane(self, leg: str, incoming: bool) -> tuple[FloatArray, FloatArray]:
        g = self.geometry
        u = np.array(LEG_DIRECTIONS[leg])
        near = u * g.box_half_size
        far = u * (g.box_half_size + g.approach_length)
        if incoming:
            offset = _right_of(-u) * g.lane_width / 2
            return far + offset, near + offset
        offset = _right_of(u) * g.lane_width / 2
        return near + offset, far + offset

    @staticmethod
    def _connector(
        p0: FloatArray, d0: FloatArray, p1: FloatArray, d1: FloatArray, spacing: float
    ) -> FloatArray:
        """Geometry from an incoming lane's end ``p0`` (driving direction ``d0``) to an
        outgoing lane's start ``p1`` (driving direction ``d1``).

        Straight when the lanes are aligned, otherwise the quarter circle tangent to both
        (the legs meet at right angles).
        """
        if np.allclose(d0, d1):
            return np.stack([p0, p1])
        left = np.array([-d0[1], d0[0]])
        turn_sign = 1.0 if float(np.dot(left, d1)) > 0 else -1.0  # +1: left turn
        radius = float(np.dot(p1 - p0, d0))
        centre = p0 + turn_sign * left * radius
        a0 = math.atan2(*(p0 - centre)[::-1])
        n = max(8, math.ceil(abs(radius) * math.pi / 2 / spacing) * 4)
        angles = a0 + turn_sign * np.linspace(0.0, math.pi / 2, n + 1)
        return centre + abs(radius) * np.stack([np.cos(angles), np.sin(angles)], axis=1)

    @cached_property
    def lane_graph(self) -> nx.DiGraph:
        """Directed graph: nodes are lane end points, edges are lanes with their geometry.

        Node names are ``(leg, "in" | "out", "start" | "end")``; every node has a ``pos``
        attribute [m]; every edge has ``geometry`` (polyline ``[N, 2]``) and ``length`` [m].
        """
        graph = nx.DiGraph()
        for leg in LEG_DIRECTIONS:
            for kind, incoming in (("in", True), ("out", False)):
                start, end = self._lane(leg, incoming)
                graph.add_node((leg, kind, "start"), pos=start)
                graph.add_node((leg, kind, "end"), pos=end)
                graph.add_edge(
                    (leg, kind, "start"),
                    (leg, kind, "end"),
                    geometry=np.stack([start, end]),
                    length=float(np.linalg.norm(end - start)),
                )
        for src in LEG_DIRECTIONS:
            for dst in LEG_DIRECTIONS:
                if src == dst:
                    continue
                p0 = graph.nodes[(src, "in", "end")]["pos"]
                p1 = graph.nodes[(dst, "out", "start")]["pos"]
                geometry = self._connector(
                    p0,
                    -np.array(LEG_DIRECTIONS[src]),
                    p1,
                    np.array(LEG_DIRECTIONS[dst]),
                    self.geometry.waypoint_spacing,
                )
                length = float(np.linalg.norm(np.diff(geometry, axis=0), axis=1).sum())
                graph.add_edge(
                    (src, "in", "end"), (dst, "out", "start"), geometry=geometry, length=length
                )
        return graph

    def route(self, origin: str, destination: str) -> Route:
        """The A* route from the far end of ``origin``'s incoming lane to the far end of
        ``destination``'s outgoing lane, as dense equally spaced waypoints."""
        for leg in (origin, destination):
            if leg not in LEG_DIRECTIONS:
                raise ValueError(f"unknown leg {leg!r}; expected one of {sorted(LEG_DIRECTIONS)}")
        graph = self.lane_graph

        def straight_line(a: tuple[str, str, str], b: tuple[str, str, str]) -> float:
            return float(np.linalg.norm(graph.nodes[a]["pos"] - graph.nodes[b]["pos"]))

        nodes = nx.astar_path(
            graph,
            (origin, "in", "start"),
            (destination, "out", "end"),
            heuristic=straight_line,
            weight="length",
        )
        pieces = [graph.edges[a, b]["geometry"] for a, b in itertools.pairwise(nodes)]
        polyline = np.concatenate([pieces[0]] + [p[1:] for p in pieces[1:]])
        return Route.from_polyline(
            polyline, self.geometry.waypoint_spacing, name=f"{origin}->{destination}"
        )

    def contains(self, xy: FloatArray) -> np.ndarray:
        """Whether positions ``[..., 2]`` lie inside the intersection box (between stop lines)."""
        half = self.geometry.box_half_size
        return np.all(np.abs(np.asarray(xy)) <= half, axis=-1)
