"""What the left turn's switching logics see: the ego and every conflict it has, as arrays.

A :class:`ConflictView` holds the ego ``[B]`` and ``C`` conflicts per episode ``[B, C]``:
column 0 is the paper's north car, the other columns the other vehicles of a scene in traffic
(``C = 1`` in the paper's scene). Each logic is written once over the ``C`` columns — the
paper's Algorithm 1 and the certificate alike — so the single-car scene is simply the case
``C = 1``. The view is a ``NamedTuple`` of arrays: the compiled kernels take it as it is.

:class:`LogicScene` is what a logic's factory may ask of the scene it supervises (typed
hooks, no probing).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit

if TYPE_CHECKING:
    from safeswitch.leftturn.config import LeftTurnConfig

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@jit
def approaching(progress: Any, point: Any, exit_: Any, approach: float) -> Any:
    """One car's half of Algorithm 1's While condition: within ``approach`` of its conflict
    point and not yet past its conflict zone's exit (arrays or scalars). A pair is "at the
    intersection" when both cars are; every scene, the tick and the logic-aware limit read the
    condition from here."""
    return (point - progress <= approach) & (progress <= exit_)


class ConflictView(NamedTuple):
    """The ego and its conflicts, as a switching logic sees them.

    Attributes:
        ego_progress: Ego's arc length along its route [m] ``[B]``.
        ego_speed: Ego's speed [m/s] ``[B]``.
        ego_throttle: Ego's actual throttle position (after the actuator lag) ``[B]``.
        ego_brake: Ego's actual brake position ``[B]``.
        present: The conflict exists: its vehicle is in the scene and its route crosses or
            merges with the ego's ``[B, C]`` (column 0, the north car, always).
        window: Algorithm 1's While condition for the pair: both within the approach distance
            of their conflict point and neither past its conflict zone ``[B, C]``.
        ego_point: The conflict point on the ego's route [m] ``[B, C]`` (the north car's:
            where the centre lines cross; another vehicle's: the middle of the ego's zone).
        ego_zone: The ego's conflict zone ``(entry, exit)`` with the paper logic's margin [m]
            ``[B, C, 2]``.
        ego_cert_zone: The same with the certified logic's margin [m] ``[B, C, 2]``.
        other_progress: The other vehicle's arc length along its route [m] ``[B, C]``.
        other_point: Its conflict point [m] ``[B, C]``.
        other_zone: Its conflict zone with the paper logic's margin [m] ``[B, C, 2]``.
        other_cert_zone: The same with the certified logic's margin [m] ``[B, C, 2]``.
        other_speed: Its speed [m/s] ``[B, C]``.
        other_top: Its top speed in the scenario [m/s] ``[B, C]`` (the certificate assumes
            its own bound instead).
        other_lead: How far the vehicle may truly be ahead of ``other_progress`` [m]
            ``[B, C]`` (0 with perfect perception; see :mod:`~safeswitch.leftturn.perception`).
        other_lag: How far it may truly be behind ``other_progress`` [m] ``[B, C]``.
        other_speed_high: Bound on its true speed [m/s] ``[B, C]`` (``other_speed`` with
            perfect perception).

    ``other_progress`` and ``other_speed`` are what the ego sees (a point estimate); a logic
    that must hold for every error within the declared bounds reads the other three.
    """

    ego_progress: FloatArray
    ego_speed: FloatArray
    ego_throttle: FloatArray
    ego_brake: FloatArray
    present: BoolArray
    window: BoolArray
    ego_point: FloatArray
    ego_zone: FloatArray
    ego_cert_zone: FloatArray
    other_progress: FloatArray
    other_point: FloatArray
    other_zone: FloatArray
    other_cert_zone: FloatArray
    other_speed: FloatArray
    other_top: FloatArray
    other_lead: FloatArray
    other_lag: FloatArray
    other_speed_high: FloatArray

    # -- the north car's conflict (column 0) in the paper's terms ------------------------------

    @property
    def ego_to_conflict(self) -> FloatArray:
        """``d_c^e``: the ego's path distance to the conflict point with the north car [m]
        ``[B]`` (negative once past it)."""
        return self.ego_point[:, 0] - self.ego_progress

    @property
    def ego_to_stop(self) -> FloatArray:
        """The ego's path distance to its stopping point, the entry of its conflict zone with
        the north car [m] ``[B]``."""
        return self.ego_zone[:, 0, 0] - self.ego_progress

    @property
    def north_to_conflict(self) -> FloatArray:
        """``d_c^n``: the north car's path distance to the conflict point [m] ``[B]``."""
        return self.other_point[:, 0] - self.other_progress[:, 0]

    @property
    def north_progress(self) -> FloatArray:
        """The north car's arc length along its route [m] ``[B]``."""
        return self.other_progress[:, 0]

    @property
    def north_speed(self) -> FloatArray:
        """``v_n`` [m/s] ``[B]``."""
        return self.other_speed[:, 0]

    @property
    def both_at_intersection(self) -> BoolArray:
        """Algorithm 1's While condition for the ego and the north car ``[B]``."""
        return self.window[:, 0]

    @property
    def batch_size(self) -> int:
        return int(self.ego_progress.shape[0])


class NorthConflict(NamedTuple):
    """The fixed geometry of the ego's conflict with the north car (arc lengths [m]).

    Attributes:
        ego_point: The conflict point on the ego's route.
        ego_zone: The ego's zone, paper margin ``(entry, exit)``.
        ego_cert_zone: The ego's zone, certified margin.
        north_point: The conflict point on the north car's route.
        north_zone: The north car's zone, paper margin.
        north_cert_zone: The north car's zone, certified margin.
        approach_distance: Algorithm 1's "at the intersection" distance.
    """

    ego_point: float
    ego_zone: tuple[float, float]
    ego_cert_zone: tuple[float, float]
    north_point: float
    north_zone: tuple[float, float]
    north_cert_zone: tuple[float, float]
    approach_distance: float

    def window(self, ego_progress: FloatArray, north_progress: FloatArray) -> BoolArray:
        """Algorithm 1's While condition for arc lengths of any (common) shape."""
        return at_intersection(ego_progress, north_progress, self)


@jit
def at_intersection(ego_progress: Any, north_progress: Any, north: NorthConflict) -> Any:
    """Algorithm 1's While condition for the ego and the north car: both within the approach
    distance of their conflict point and not yet out of their conflict zone; a bool array for
    arrays, a bool for scalars."""
    d = north.approach_distance
    ego = approaching(ego_progress, north.ego_point, north.ego_zone[1], d)
    return ego & approaching(north_progress, north.north_point, north.north_zone[1], d)


class _NorthColumns(NamedTuple):
    """The fixed columns of a one-conflict view for one batch size (shared between ticks:
    views are read, never written)."""

    present: BoolArray
    ego_point: FloatArray
    ego_zone: FloatArray
    ego_cert_zone: FloatArray
    other_point: FloatArray
    other_zone: FloatArray
    other_cert_zone: FloatArray
    zero: FloatArray


_FIXED: dict[tuple[NorthConflict, int], _NorthColumns] = {}


def _north_columns(geometry: NorthConflict, batch: int) -> _NorthColumns:
    key = (geometry, batch)
    cached = _FIXED.get(key)
    if cached is None:

        def column(value: float) -> FloatArray:
            return np.full((batch, 1), value)

        def zone(bounds: tuple[float, float]) -> FloatArray:
            return np.ascontiguousarray(
                np.broadcast_to(np.asarray(bounds, dtype=np.float64), (batch, 1, 2))
            )

        g = geometry
        cached = _NorthColumns(
            np.ones((batch, 1), dtype=np.bool_), column(g.ego_point), zone(g.ego_zone),
            zone(g.ego_cert_zone), column(g.north_point), zone(g.north_zone),
            zone(g.north_cert_zone), column(0.0),
        )  # fmt: skip
        for array in cached:
            array.setflags(write=False)
        if len(_FIXED) > 64:  # a few batch sizes per process; never unbounded
            _FIXED.clear()
        _FIXED[key] = cached
    return cached


def north_view(
    geometry: NorthConflict,
    ego_progress: FloatArray,
    ego_speed: FloatArray,
    ego_throttle: FloatArray,
    ego_brake: FloatArray,
    north_progress: FloatArray,
    north_speed: FloatArray,
    north_top: FloatArray,
    window: BoolArray | None = None,
    uncertainty: tuple[FloatArray, FloatArray, FloatArray] | None = None,
) -> ConflictView:
    """The view of the paper's scene: one conflict, the north car (``C = 1``). ``window``:
    Algorithm 1's While condition if already known (else computed from the arc lengths);
    ``uncertainty``: the north car's lead, lag and speed bound ``[B]`` each (see
    :class:`ConflictView`; ``None``: perfect perception)."""
    batch = ego_progress.shape[0]
    fixed = _north_columns(geometry, batch)
    if window is None:
        window = geometry.window(ego_progress, north_progress)
    return ConflictView(
        ego_progress=ego_progress,
        ego_speed=ego_speed,
        ego_throttle=ego_throttle,
        ego_brake=ego_brake,
        present=fixed.present,
        window=window.reshape(batch, 1),
        ego_point=fixed.ego_point,
        ego_zone=fixed.ego_zone,
        ego_cert_zone=fixed.ego_cert_zone,
        other_progress=north_progress.reshape(batch, 1),
        other_point=fixed.other_point,
        other_zone=fixed.other_zone,
        other_cert_zone=fixed.other_cert_zone,
        other_speed=north_speed.reshape(batch, 1),
        other_top=north_top.reshape(batch, 1),
        other_lead=fixed.zero if uncertainty is None else uncertainty[0].reshape(batch, 1),
        other_lag=fixed.zero if uncertainty is None else uncertainty[1].reshape(batch, 1),
        other_speed_high=(
            north_speed.reshape(batch, 1)
            if uncertainty is None
            else uncertainty[2].reshape(batch, 1)
        ),
    )


class Phantoms(NamedTuple):
    """Vehicles not yet in the scene that the certificate must beat all the same: one per
    movement crossing the ego's that a stream can bring (none in the paper's scene).

    Attributes:
        ego_zone: The ego's zone with each such movement, certified margin [m] ``[P, 2]``.
        entry: The entry of the movement's own zone, measured from the start of its
            approach [m] ``[P]`` (a phantom can be there no sooner than ``entry / top``).
    """

    ego_zone: FloatArray
    entry: FloatArray

    @classmethod
    def none(cls) -> Phantoms:
        return cls(np.empty((0, 2)), np.empty(0))


@runtime_checkable
class LogicScene(Protocol):
    """What a left-turn switching logic's factory may ask of the scene it supervises."""

    @property
    def config(self) -> LeftTurnConfig:
        """The scene's configuration (the logics' parameters among it)."""
        ...

    @property
    def north_conflict(self) -> NorthConflict:
        """The geometry of the ego's conflict with the north car."""
        ...

    def phantoms(self) -> Phantoms:
        """The vehicles still to come that the certificate must beat (certified margin)."""
        ...

    def ego_curvature(self) -> tuple[float, FloatArray]:
        """The ego's route: its waypoint spacing [m] and ``|κ|`` at each waypoint [1/m]."""
        ...
