"""Paths as dense, uniformly spaced waypoints, and batched path utilities.

Every route is resampled to a constant waypoint spacing. That makes the waypoint index of an arc
length a division instead of a search, which is what lets :meth:`RouteSet.project` track a
batch of thousands of vehicles with a fixed, small amount of work per vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import flat, jit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def resample_polyline(points: FloatArray, spacing: float) -> FloatArray:
    """Resample a polyline to points exactly ``spacing`` apart along its arc.

    The last point lies at the largest whole multiple of ``spacing`` not beyond the end (so up to
    one spacing of the tail is dropped), which lets every route share one exact spacing.

    Args:
        points: Vertices, shape ``[N, 2]`` [m].
        spacing: Arc length between consecutive output points [m].

    Returns:
        Points of shape ``[M, 2]``, the first one equal to ``points[0]``.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
        raise ValueError(f"a polyline needs shape [N>=2, 2], got {points.shape}")
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing!r}")
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])  # drop repeated vertices
    points, s = points[keep], np.concatenate([[0.0], np.cumsum(seg[seg > 1e-9])])
    if s[-1] < spacing:
        raise ValueError(f"polyline of length {s[-1]:.3f} m is shorter than one spacing")
    s_new = spacing * np.arange(int(np.floor(s[-1] / spacing + 1e-9)) + 1)
    return np.stack([np.interp(s_new, s, points[:, 0]), np.interp(s_new, s, points[:, 1])], axis=1)


@dataclass(frozen=True)
class Route:
    """A path as waypoints equally spaced along its arc.

    Attributes:
        points: Waypoints, shape ``[N, 2]`` [m].
        spacing: Arc length between consecutive waypoints [m]. On curves the chord between two
            waypoints is a hair shorter (relative error ``(spacing·κ)²/24``, below 1e-4 here).
        name: Human-readable name, e.g. ``"south->west"``.
    """

    points: FloatArray
    spacing: float
    name: str = ""

    def __post_init__(self) -> None:
        steps = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        if len(self.points) < 2 or not np.allclose(steps, self.spacing, rtol=1e-3, atol=0.0):
            raise ValueError(
                f"Route {self.name!r}: waypoints must be {self.spacing} m apart; "
                "use Route.from_polyline"
            )

    @classmethod
    def from_polyline(cls, points: FloatArray, spacing: float, name: str = "") -> Route:
        """Build a route from any polyline by resampling it to ``spacing``."""
        return cls(resample_polyline(points, spacing), spacing, name)

    @property
    def length(self) -> float:
        """Arc length of the whole route [m]."""
        return self.spacing * (len(self.points) - 1)

    @property
    def arc_length(self) -> FloatArray:
        """Arc length at each waypoint, shape ``[N]`` [m]."""
        return self.spacing * np.arange(len(self.points), dtype=np.float64)

    @property
    def heading(self) -> FloatArray:
        """Heading of the path at each waypoint, shape ``[N]`` [rad], counter-clockwise from +x."""
        d = np.gradient(self.points, axis=0)
        return np.arctan2(d[:, 1], d[:, 0])

    @property
    def curvature(self) -> FloatArray:
        """Signed curvature at each waypoint, shape ``[N]`` [1/m], positive turning left."""
        return np.gradient(np.unwrap(self.heading), self.spacing)

    def pose_at(self, s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Position ``[..., 2]`` [m] and heading ``[...]`` [rad] at arc lengths ``s`` [m]."""
        return RouteSet([self]).pose_at(np.zeros(np.shape(s), dtype=np.intp), s)

    def project(self, xy: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Global projection of positions onto the route.

        Args:
            xy: Positions, shape ``[..., 2]`` [m].

        Returns:
            Arc length of the nearest route point [m], signed lateral deviation [m] (positive when
            the position is left of the route) and the route heading there [rad].
        """
        return RouteSet([self]).project_global(np.zeros(np.shape(xy)[:-1], dtype=np.intp), xy)

    def arc_length_of(self, point: FloatArray) -> float:
        """Distance along the route from its start to the route point nearest ``point`` [m]."""
        s, _, _ = self.project(np.asarray(point, dtype=np.float64))
        return float(s)


class RouteSet:
    """Several routes stacked for batched look-ups: each query names the route it is about.

    Routes are padded to a common length by extending their last segment in a straight line, so
    queries a little past a route's end stay well defined (a car does not fall off its route).
    Internally every per-waypoint quantity is one flat array indexed by
    ``route_index · size + waypoint``: a 1-D ``np.take`` is several times faster than
    multi-dimensional fancy indexing, and this is the simulator's hottest path.

    Args:
        routes: The routes; all must share the same waypoint spacing.
        pad: Number of straight extension waypoints appended to every route.
    """

    #: Steps of the walk that moves a vehicle's segment index from its previous one to the
    #: nearest one. Each step jumps by the whole number of segments the vehicle is ahead of (or
    #: behind) the current one, so one step is exact on straights; three cover any motion of
    #: under a few metres per tick on the curves here.
    WALK_STEPS = 3

    def __init__(self, routes: list[Route], pad: int = 16) -> None:
        if not routes:
            raise ValueError("RouteSet needs at least one route")
        spacing = routes[0].spacing
        for route in routes:
            if route.spacing != spacing:
                raise ValueError(
                    f"all routes must share one spacing; {route.name!r} has {route.spacing} "
                    f"and {routes[0].name!r} has {spacing}"
                )
        self.routes = list(routes)
        self.spacing = spacing
        self.size = max(len(r.points) for r in routes) + pad
        stacked = np.empty((len(routes), self.size, 2))
        for i, route in enumerate(routes):
            n = len(route.points)
            direction = route.points[-1] - route.points[-2]
            extra = np.arange(1, self.size - n + 1, dtype=np.float64)[:, None]
            stacked[i, :n] = route.points
            stacked[i, n:] = route.points[-1] + extra * direction
        self.points = stacked
        d = np.diff(stacked, axis=1)
        d = np.concatenate([d, d[:, -1:]], axis=1)  # same length as the points
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        # Tangent heading at each waypoint (central differences), unwrapped along each route so
        # that it can be interpolated linearly between waypoints.
        g = np.asarray(np.gradient(stacked, axis=1))
        heading = np.unwrap(np.arctan2(g[..., 1], g[..., 0]), axis=1)
        self._px, self._py = stacked[..., 0].ravel(), stacked[..., 1].ravel()
        self._dx, self._dy = d[..., 0].ravel(), d[..., 1].ravel()
        self._heading = heading.ravel()
        self.lengths = np.array([r.length for r in routes])
        #: What the compiled look-ups read: per-waypoint arrays, rows x, y, dx, dy, heading.
        self.tables = np.stack([self._px, self._py, self._dx, self._dy, self._heading])
        self.tables.flags.writeable = False

    def base_index(self, route_index: IntArray) -> IntArray:
        """Flat index of each named route's first waypoint (pass it to the ``*_flat`` calls)."""
        return np.asarray(route_index, dtype=np.intp) * self.size

    def pose_at(self, route_index: IntArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Position ``[..., 2]`` and heading ``[...]`` at arc length ``s`` on the named routes."""
        x, y, heading = self.pose_at_flat(self.base_index(route_index), np.asarray(s, float))
        return np.stack([x, y], axis=-1), heading

    def pose_at_flat(
        self, base: IntArray, s: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """x [m], y [m] and heading [rad] at arc lengths ``s``; ``base`` from :meth:`base_index`."""
        shape = np.broadcast_shapes(np.shape(base), np.shape(s))
        x, y, heading = np.empty(shape), np.empty(shape), np.empty(shape)
        _map_pose(
            self.tables,
            self.spacing,
            self.size - 2,
            np.ascontiguousarray(np.broadcast_to(base, shape)).reshape(-1),
            flat(s, shape),
            x.reshape(-1),
            y.reshape(-1),
            heading.reshape(-1),
        )
        return x, y, heading

    def _heading_at(self, i: IntArray, frac: FloatArray) -> FloatArray:
        h0 = self._heading.take(i)
        return h0 + (self._heading.take(i + 1) - h0) * (frac / self.spacing)

    def project(
        self, route_index: IntArray, xy: FloatArray, s_guess: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Project positions onto their routes, starting from a previous arc length.

        Args:
            route_index: Which route each position belongs to, shape ``[...]``.
            xy: Positions, shape ``[..., 2]`` [m].
            s_guess: Previous arc length of each position, shape ``[...]`` [m]; the nearest
                route point must lie within a few metres of it.

        Returns:
            Arc length ``s`` [m], signed lateral deviation (positive left of the route) [m] and
            route heading at the projection [rad], each of shape ``[...]``.
        """
        xy = np.asarray(xy, dtype=np.float64)
        return self.project_flat(
            self.base_index(route_index),
            xy[..., 0],
            xy[..., 1],
            np.asarray(s_guess, dtype=np.float64),
        )

    def project_flat(
        self, base: IntArray, x: FloatArray, y: FloatArray, s_guess: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`project` with ``base`` from :meth:`base_index` and coordinates split."""
        i, s, along, lateral = self._locate(base, x, y, s_guess)
        return s, lateral, self._heading_at(i, along)

    def track_flat(
        self, base: IntArray, x: FloatArray, y: FloatArray, s_guess: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Arc length and lateral deviation only (the simulator's per-tick route tracking)."""
        _, s, _, lateral = self._locate(base, x, y, s_guess)
        return s, lateral

    def _locate(
        self, base: IntArray, x: FloatArray, y: FloatArray, s_guess: FloatArray
    ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
        """Flat segment index, arc length, distance along the segment and lateral deviation."""
        shape = np.broadcast_shapes(np.shape(base), np.shape(x), np.shape(y), np.shape(s_guess))
        i = np.empty(shape, dtype=np.intp)
        s, along, lateral = np.empty(shape), np.empty(shape), np.empty(shape)
        _map_locate(
            self.tables,
            self.spacing,
            self.size - 2,
            self.WALK_STEPS,
            np.ascontiguousarray(np.broadcast_to(base, shape)).reshape(-1),
            flat(x, shape),
            flat(y, shape),
            flat(s_guess, shape),
            i.reshape(-1),
            s.reshape(-1),
            along.reshape(-1),
            lateral.reshape(-1),
        )
        return i, s, along, lateral

    def project_global(
        self, route_index: IntArray, xy: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Like :meth:`project` but searching the whole route (for set-up and analysis)."""
        xy = np.asarray(xy, dtype=np.float64)
        base = self.base_index(route_index)[..., None]
        i = base + np.arange(self.size - 1)
        rx = xy[..., 0, None] - self._px.take(i)
        ry = xy[..., 1, None] - self._py.take(i)
        dx, dy = self._dx.take(i), self._dy.take(i)
        along = np.clip(rx * dx + ry * dy, 0.0, self.spacing)
        dist2 = (rx - along * dx) ** 2 + (ry - along * dy) ** 2
        best = np.argmin(dist2, axis=-1)
        k = best
        i_best = base[..., 0] + k
        along_best = np.take_along_axis(along, best[..., None], -1)[..., 0]
        lateral = np.take_along_axis(dx * ry - dy * rx, best[..., None], -1)[..., 0]
        return k * self.spacing + along_best, lateral, self._heading_at(i_best, along_best)

    def preview_offset(
        self,
        route_index: IntArray,
        s: FloatArray,
        xy: FloatArray,
        yaw: FloatArray,
        lookahead: float,
    ) -> FloatArray:
        """Lateral offset of the route point ``lookahead`` metres ahead, in the vehicle's frame.

        Positive when that point lies to the vehicle's left. On a straight route with the vehicle
        on the centre line and aligned it is 0; in a curve of radius R it is about
        ``lookahead² / (2R)``, which gives a lane keeper built on it a built-in curvature
        feed-forward.
        """
        xy = np.asarray(xy, dtype=np.float64)
        return self.preview_offset_flat(
            self.base_index(route_index),
            np.asarray(s, float),
            xy[..., 0],
            xy[..., 1],
            np.asarray(yaw),
            lookahead,
        )

    def preview_offset_flat(
        self,
        base: IntArray,
        s: FloatArray,
        x: FloatArray,
        y: FloatArray,
        yaw: FloatArray,
        lookahead: float,
    ) -> FloatArray:
        """:meth:`preview_offset` with ``base`` from :meth:`base_index` and coordinates split."""
        yaw = np.asarray(yaw, dtype=np.float64)
        return self.preview_offset_axes(base, s, x, y, np.cos(yaw), np.sin(yaw), lookahead)

    def preview_offset_axes(
        self,
        base: IntArray,
        s: FloatArray,
        x: FloatArray,
        y: FloatArray,
        cos_yaw: FloatArray,
        sin_yaw: FloatArray,
        lookahead: float,
    ) -> FloatArray:
        """:meth:`preview_offset_flat` with the heading as a unit vector (see :func:`preview`)."""
        args = (base, s, x, y, cos_yaw, sin_yaw)
        shape = np.broadcast_shapes(*(np.shape(a) for a in args))
        out = np.empty(shape)
        _map_preview(
            self.tables, self.spacing, self.size - 2,
            np.ascontiguousarray(np.broadcast_to(base, shape)).reshape(-1),
            flat(s, shape), flat(x, shape), flat(y, shape), flat(cos_yaw, shape),
            flat(sin_yaw, shape), lookahead, out.reshape(-1),
        )  # fmt: skip
        return out


def wrap_angle(angle: FloatArray) -> FloatArray:
    """Wrap angles to ``[-pi, pi]`` [rad]."""
    angle = np.asarray(angle)
    return angle - (2 * np.pi) * np.rint(angle * (1 / (2 * np.pi)))


@jit
def _map_pose(
    tables: FloatArray,
    spacing: float,
    k_max: int,
    base: IntArray,
    s: FloatArray,
    x_out: FloatArray,
    y_out: FloatArray,
    heading_out: FloatArray,
) -> None:
    """:meth:`RouteSet.pose_at_flat`, element by element (``tables`` rows: x, y, dx, dy and
    heading of every flat waypoint)."""
    for n in range(s.shape[0]):
        x_out[n], y_out[n], heading_out[n] = pose(tables, spacing, k_max, base[n], s[n])


@jit
def _segment(spacing: float, k_max: int, base: int, s: float) -> tuple[int, float]:
    """The flat index of the waypoint that starts the segment holding arc length ``s`` on the
    route starting at ``base``, and how far into the segment ``s`` lies [m]."""
    k = min(max(math.floor(s / spacing), 0), k_max)
    return base + k, s - k * spacing


@jit
def pose(
    tables: FloatArray, spacing: float, k_max: int, base: int, s: float
) -> tuple[float, float, float]:
    """Position [m] and heading [rad] at arc length ``s`` on the route starting at flat
    waypoint ``base`` (linear between waypoints)."""
    i, frac = _segment(spacing, k_max, base, s)
    h0 = tables[4, i]
    return (
        tables[0, i] + frac * tables[2, i],
        tables[1, i] + frac * tables[3, i],
        h0 + (tables[4, i + 1] - h0) * (frac / spacing),
    )


@jit
def pose_axes(
    tables: FloatArray, axes: FloatArray, spacing: float, k_max: int, base: int, s: float
) -> tuple[float, float, float, float]:
    """:func:`pose` with the heading as its unit vector ``(cos, sin)``: read from ``axes``
    (:func:`heading_axes`) where the heading does not change over the segment — on straights,
    no trigonometry — else computed; the same bits either way."""
    x, y, heading = pose(tables, spacing, k_max, base, s)
    i, _ = _segment(spacing, k_max, base, s)
    if tables[4, i + 1] == tables[4, i]:  # then heading is tables[4, i] exactly
        return x, y, axes[0, i], axes[1, i]
    return x, y, math.cos(heading), math.sin(heading)


def heading_axes(tables: FloatArray) -> FloatArray:
    """``[2, W]``: the cosine and sine of every waypoint's heading (what :func:`pose_axes`
    reads), computed by the same compiled ``math.cos``/``math.sin`` as its fallback."""
    out = np.empty((2, tables.shape[1]))
    _cos_sin(np.ascontiguousarray(tables[4]), out)
    return out


@jit
def _cos_sin(angles: FloatArray, out: FloatArray) -> None:
    for i in range(angles.shape[0]):
        out[0, i], out[1, i] = math.cos(angles[i]), math.sin(angles[i])


@jit
def _map_locate(
    tables: FloatArray,
    spacing: float,
    k_max: int,
    walk_steps: int,
    base: IntArray,
    x: FloatArray,
    y: FloatArray,
    s_guess: FloatArray,
    i_out: IntArray,
    s_out: FloatArray,
    along_out: FloatArray,
    lateral_out: FloatArray,
) -> None:
    """:func:`locate`, element by element."""
    for n in range(x.shape[0]):
        i_out[n], s_out[n], along_out[n], lateral_out[n] = locate(
            tables, spacing, k_max, walk_steps, base[n], x[n], y[n], s_guess[n]
        )


@jit
def locate(
    tables: FloatArray,
    spacing: float,
    k_max: int,
    walk_steps: int,
    base: int,
    x: float,
    y: float,
    s_guess: float,
) -> tuple[int, float, float, float]:
    """One position on its route: walk from the segment of ``s_guess`` to the nearest one, then
    project. Returns the flat segment index, the arc length, the distance along the segment and
    the lateral deviation (``tables`` rows: x, y, dx, dy, heading of every flat waypoint)."""
    k = min(max(math.floor(s_guess / spacing), 0), k_max)
    for _ in range(walk_steps):
        i = base + k
        along = (x - tables[0, i]) * tables[2, i] + (y - tables[1, i]) * tables[3, i]
        k = min(max(k + math.floor(along / spacing), 0), k_max)
    i = base + k
    rx, ry = x - tables[0, i], y - tables[1, i]
    dx, dy = tables[2, i], tables[3, i]
    along = min(max(rx * dx + ry * dy, 0.0), spacing)
    return i, k * spacing + along, along, dx * ry - dy * rx


@jit
def preview(
    tables: FloatArray, spacing: float, k_max: int, base: int, s: float, x: float, y: float,
    cos_yaw: float, sin_yaw: float, lookahead: float,
) -> float:  # fmt: skip
    """Lateral offset of the route point ``lookahead`` metres ahead of arc length ``s``, in the
    frame of a vehicle at ``(x, y)`` heading ``(cos_yaw, sin_yaw)`` [m] (positive: to its left)."""
    tx, ty, _ = pose(tables, spacing, k_max, base, s + lookahead)
    return cos_yaw * (ty - y) - sin_yaw * (tx - x)


@jit
def _map_preview(
    tables: FloatArray, spacing: float, k_max: int, base: IntArray, s: FloatArray,
    x: FloatArray, y: FloatArray, cos_yaw: FloatArray, sin_yaw: FloatArray, lookahead: float,
    out: FloatArray,
) -> None:  # fmt: skip
    for n in range(s.shape[0]):
        out[n] = preview(
            tables, spacing, k_max, base[n], s[n], x[n], y[n], cos_yaw[n], sin_yaw[n], lookahead
        )
