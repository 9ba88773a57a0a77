"""One SUMO simulation of the intersection, stepped from Python through ``libsumo``.

``libsumo`` runs SUMO inside this process (no server, no port, no child process) and allows one
simulation per process: :class:`SumoPlant` refuses a second one while the first is open (use
worker processes, :func:`~safeswitch.sumo.task.make_sumo_vec_env`, for several).

Vehicles SUMO drives use its default car-following model (Krauss) without dawdling
(``sigma = 0``: deterministic) and its junction model; a driver that *never yields* (the paper's
north car) ignores the right of way of foes approaching the junction and of foes inside it
(speed mode 55: bits 3 off and 5 on, see SUMO's TraCI documentation of ``setSpeedMode``) but
still keeps its distance to a leader. In traffic, where the other foes are SUMO's own drivers,
a driver who never yields ignores the ego only (the generic parameter
``junctionModel.ignoreIDs``, SUMO's "transient junction model parameters") and gives way to
everyone else by SUMO's rules, as the embedded traffic's non-yielding drivers do. The ego is not
driven by SUMO: its pose comes from safeswitch's plant every tick (``moveToXY``), so SUMO's
drivers see it and SUMO's collision detection (junctions included) checks it.

Positions: safeswitch's are footprint centres, SUMO's front bumpers; headings are converted
from counter-clockwise-from-east radians to SUMO's clockwise-from-north degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from safeswitch.sim.road import LEG_DIRECTIONS
from safeswitch.sumo.network import SumoMissingError, binary, edge_id

#: SUMO's speed mode for a driver who never yields (see the module docstring).
NEVER_YIELDS = 55


def import_libsumo() -> Any:
    try:
        import libsumo
    except ImportError as exc:
        raise SumoMissingError("libsumo is not installed: pip install 'safeswitch[sumo]'") from exc
    return libsumo


def to_sumo_angle(heading: float) -> float:
    """safeswitch heading [rad, counter-clockwise from east] → SUMO angle [deg, clockwise
    from north]."""
    return (90.0 - math.degrees(heading)) % 360.0


def from_sumo_angle(angle: float) -> float:
    return math.radians(90.0 - angle)


@dataclass(frozen=True)
class Pose:
    """A vehicle as SUMO has it, converted: centre [m], heading [rad], speed [m/s]."""

    x: float
    y: float
    heading: float
    speed: float


class SumoPlant:
    """One SUMO simulation (see the module docstring).

    Args:
        net: The network (:func:`~safeswitch.sumo.network.network_file`).
        dt: Step length [s].
        length: Vehicle length [m].
        width: Vehicle width [m].
    """

    _open: ClassVar[SumoPlant | None] = None

    def __init__(self, net: Path, dt: float, length: float, width: float) -> None:
        self.net, self.dt, self.length, self.width = Path(net), dt, length, width
        self._sumo = import_libsumo()
        self._started = False
        self.collisions: list[tuple[str, str]] = []

    def _arguments(self, seed: int) -> list[str]:
        return [
            str(binary("sumo")), "--net-file", str(self.net), "--step-length", f"{self.dt:g}",
            "--begin", "0", "--seed", str(seed), "--collision.action", "warn",
            "--collision.check-junctions", "true", "--no-step-log", "true",
            "--no-warnings", "true", "--time-to-teleport", "-1", "--default.speeddev", "0",
        ]  # fmt: skip

    def reset(self, seed: int = 0) -> None:
        """A fresh simulation at time 0 with the routes and vehicle types defined.

        Raises:
            RuntimeError: Another plant is open in this process.
        """
        if SumoPlant._open is not None and SumoPlant._open is not self:
            raise RuntimeError(
                "libsumo runs one SUMO simulation per process and another is open here; close "
                "it first, or use make_sumo_vec_env (worker processes) for several"
            )
        s = self._sumo
        if self._started:
            s.load(self._arguments(seed)[1:])
        else:
            s.start(self._arguments(seed))
            self._started = True
        SumoPlant._open = self
        for origin in LEG_DIRECTIONS:
            for destination in LEG_DIRECTIONS:
                if origin != destination:
                    s.route.add(
                        f"{origin}->{destination}",
                        [edge_id(origin, True), edge_id(destination, False)],
                    )
        s.vehicletype.copy("DEFAULT_VEHTYPE", "car")
        t = s.vehicletype
        t.setLength("car", self.length)
        t.setWidth("car", self.width)
        t.setMinGap("car", 2.0)
        t.setImperfection("car", 0.0)
        t.setAccel("car", 1.5)
        t.setDecel("car", 2.0)
        t.setEmergencyDecel("car", 8.0)
        self.collisions = []

    def add(
        self, vid: str, route: str, progress: float, speed: float, top: float, yields: bool,
        safe_speed: bool = False, force: bool = False, ignores: str | None = None,
    ) -> None:  # fmt: skip
        """Insert a vehicle SUMO drives: on ``route`` (``origin->destination``) ``progress``
        metres from the start of its approach (its centre), at ``speed``, never faster than
        ``top`` [m/s]; ``safe_speed``: at the highest speed up to ``top`` that SUMO finds safe
        behind the vehicles ahead (``departSpeed="max"``). SUMO inserts it on the next step on
        which its insertion checks pass (room behind and ahead, able to stop at a give-way
        line); ``force`` puts it on its lane now whatever they say (``moveTo``; a scene that
        starts with it there). A driver who does not yield ignores every foe at the junction
        (speed mode 55), or with ``ignores`` (a vehicle id) that one only and keeps SUMO's
        rules with the others (``junctionModel.ignoreIDs``)."""
        s = self._sumo
        s.vehicle.add(
            vid, route, "car", depart="now", departLane="first",
            departPos=f"{progress + self.length / 2:.4f}",
            departSpeed="max" if safe_speed else f"{speed:.4f}",
        )  # fmt: skip
        if force:
            origin = route.split("->")[0]
            s.vehicle.moveTo(vid, f"{edge_id(origin, True)}_0", progress + self.length / 2)
        s.vehicle.setMaxSpeed(vid, top)
        if not yields and ignores is not None:
            s.vehicle.setParameter(vid, "junctionModel.ignoreIDs", ignores)
        elif not yields:
            s.vehicle.setSpeedMode(vid, NEVER_YIELDS)

    def add_ego(self, route: str, progress: float, speed: float) -> None:
        """Insert the ego (moved by :meth:`place` from then on)."""
        s = self._sumo
        s.vehicle.add(
            "ego", route, "car", depart="now", departLane="first",
            departPos=f"{progress + self.length / 2:.4f}", departSpeed=f"{speed:.4f}",
        )  # fmt: skip
        s.vehicle.setSpeedMode("ego", 0)

    def place(self, vid: str, x: float, y: float, heading: float) -> None:
        """Put a vehicle where safeswitch's plant has it (centre and heading)."""
        c, s_ = math.cos(heading), math.sin(heading)
        half = self.length / 2
        self._sumo.vehicle.moveToXY(
            vid, "", 0, x + half * c, y + half * s_, to_sumo_angle(heading), keepRoute=2
        )

    def step(self) -> None:
        """One step; SUMO's collisions of the step are appended to :attr:`collisions`."""
        s = self._sumo
        s.simulationStep()
        for c in s.simulation.getCollisions():
            self.collisions.append((c.collider, c.victim))

    def remove(self, vid: str) -> None:
        """Take a vehicle out of the simulation."""
        self._sumo.vehicle.remove(vid)

    def vehicles(self) -> tuple[str, ...]:
        return tuple(self._sumo.vehicle.getIDList())

    def read(self, vid: str) -> Pose | None:
        """A vehicle's centre, heading and speed (``None``: it is not in the network — it has
        left, or SUMO has not inserted it yet)."""
        v = self._sumo.vehicle
        try:
            x, y = v.getPosition(vid)
        except self._sumo.TraCIException:
            return None
        if x == self._sumo.constants.INVALID_DOUBLE_VALUE:  # added but not inserted yet
            return None
        heading = from_sumo_angle(v.getAngle(vid))
        half = self.length / 2
        return Pose(
            x - half * math.cos(heading), y - half * math.sin(heading), heading, v.getSpeed(vid)
        )

    def close(self) -> None:
        """End the simulation (idempotent)."""
        if self._started:
            self._sumo.close()
            self._started = False
        if SumoPlant._open is self:
            SumoPlant._open = None
