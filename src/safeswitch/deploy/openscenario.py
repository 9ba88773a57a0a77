"""Scenarios out and in: the left turn as ASAM OpenSCENARIO 1.0 with its OpenDRIVE road.

A scenario file holds what another simulator needs to drive it again — the format CARLA's
ScenarioRunner and esmini replay:

* the road: ``intersection.xodr`` beside it, the four legs (one lane each way, the scene's lane
  width and approach length) and a junction with a connecting road for every turn (written by
  PyPI ``scenariogeneration``; its connecting roads are spiral–arc–spiral, close to but not
  exactly the embedded simulator's quarter circles — the vehicles' trajectories below are in
  world coordinates and do not depend on them);
* ``Ego`` and ``North``, with their dimensions, their start (world position and heading) and
  speed, the scenario's parameters as ``ParameterDeclarations`` (SI units, every digit:
  ``EgoStartDistance``, ``EgoSpeed``, ``NorthSpeed``, ``ArrivalOffset``; the speeds of the
  ``Init`` refer to them);
* the ego's route (``AssignRouteAction``: its start, the junction's exit, its destination), so
  the agent under test drives it; the oncoming car's trajectory of a run
  (``FollowTrajectoryAction``, a polyline with absolute times, one vertex per tick);
* a stop trigger: the episode's horizon, or the ego colliding.

:func:`read_scenarios` parses such a file back into the scenario it was written from
(``safeswitch evaluate --scenarios openscenario:PATH``): the parameters are read, and the
``Init`` positions must match what this scene places for them (a file written for another
geometry, or edited by hand, is refused rather than evaluated as something else).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.io import replacing
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask, TaskState

#: The OpenSCENARIO version written (CARLA's ScenarioRunner reads 1.0; esmini 1.0–1.3).
OSC_MINOR = 0
#: The road file every scenario of a folder refers to.
ROAD_FILE = "intersection.xodr"
#: (OpenSCENARIO parameter, :class:`Scenarios` field, unit).
PARAMETERS = (
    ("EgoStartDistance", "ego_start_distance", "m"),
    ("EgoSpeed", "ego_speed", "m/s"),
    ("NorthSpeed", "north_speed", "m/s"),
    ("ArrivalOffset", "arrival_offset", "s"),
)
#: Time between two vertices of a recorded trajectory [s] (and the episode's last tick): the
#: replaying simulator interpolates linearly between them; at the oncoming car's speeds a
#: vertex every 0.1 s stays within millimetres of the tick-by-tick path on its straight lane.
TRAJECTORY_STEP_S = 0.1
#: The parameter naming the traffic of a scene (``none``: the paper's scene, the only one
#: :func:`read_scenarios` reads back).
TRAFFIC = "Traffic"
#: The vehicles' height [m] (the embedded simulator is planar).
HEIGHT = 1.5
#: A parsed start position may differ from this scene's by this much [m] (written with every
#: digit, it differs by nothing).
POSITION_TOLERANCE = 1e-6


class OpenScenarioError(ValueError):
    """A scenario file cannot be written or read as asked; the message names the file."""


@dataclass
class Track:
    """One vehicle's trajectory in a run: per tick, ``[T]`` each.

    Attributes:
        time: Simulated time [s].
        x: East [m].
        y: North [m].
        yaw: Heading, counter-clockwise from east [rad].
        speed: [m/s].
    """

    time: NDArray[np.float64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    yaw: NDArray[np.float64]
    speed: NDArray[np.float64]


def schema_file() -> Path:
    """The ASAM OpenSCENARIO 1.0 XSD shipped with ``scenariogeneration``."""
    import scenariogeneration

    path = Path(scenariogeneration.__file__).resolve().parent.parent / "schemas"
    path = path / f"OpenSCENARIO_1_{OSC_MINOR}.xsd"
    if not path.is_file():
        raise OpenScenarioError(
            f"the OpenSCENARIO schema {path} is missing from scenariogeneration"
        )
    return path


@cache
def _schema() -> Any:
    import xmlschema

    return xmlschema.XMLSchema(str(schema_file()))


def validate(path: Path) -> None:
    """Check ``path`` against the ASAM OpenSCENARIO schema.

    Raises:
        OpenScenarioError: The file is not schema-valid (the first errors named).
    """
    schema = _schema()
    errors = [f"{e.path}: {e.reason}" for e in schema.iter_errors(str(path))]
    if errors:
        raise OpenScenarioError(
            f"{path} is not valid OpenSCENARIO 1.{OSC_MINOR}: " + "; ".join(errors[:3])
        )


def road_network(task: LeftTurnTask) -> Any:
    """The scene's intersection as OpenDRIVE: four legs of ``approach_length`` meeting in a
    junction whose centre is the origin, ``box_half_size`` from each stop line."""
    from scenariogeneration import xodr

    g = task.config.geometry
    odr = xodr.OpenDrive("safeswitch intersection")
    junction = xodr.CommonJunctionCreator(100, "junction", startnum=100)
    legs = {"east": 0.0, "north": math.pi / 2, "west": math.pi, "south": 1.5 * math.pi}
    roads = []
    for index, angle in enumerate(legs.values(), start=1):
        road = xodr.create_road(
            xodr.Line(g.approach_length),
            index,
            left_lanes=1,
            right_lanes=1,
            lane_width=g.lane_width,
        )
        junction.add_incoming_road_circular_geometry(road, g.box_half_size, angle, "predecessor")
        roads.append(road)
    for a in range(1, 5):
        for b in range(a + 1, 5):
            junction.add_connection(a, b)
    # The first leg starts at the east stop line; the junction creator places the others.
    roads[0].planview.set_start_point(g.box_half_size, 0.0, 0.0)
    for road in roads:
        odr.add_road(road)
    odr.add_junction_creator(junction)
    odr.adjust_roads_and_lanes()
    return odr


@dataclass
class Run:
    """The trajectories of one episode: the ego, the oncoming car and, in traffic, every other
    vehicle from the tick it entered to the tick it left (its :attr:`Track.time` says when)."""

    ego: Track
    north: Track
    others: list[Track]


#: Consecutive positions of a slot farther apart than this [m] are two vehicles (a slot freed
#: and filled again on one tick); a car moves at most 0.35 m per 20 ms tick.
_JUMP_M = 5.0


def _appearances(
    active: NDArray[np.bool_], x: NDArray[np.float64], y: NDArray[np.float64]
) -> list[tuple[int, int]]:
    """``(first, last)`` ticks of each vehicle that held one slot."""
    out = []
    start = None
    for t in range(len(active)):
        jumped = (
            start is not None
            and active[t]
            and math.hypot(x[t] - x[t - 1], y[t] - y[t - 1]) > _JUMP_M
        )
        if start is not None and (not active[t] or jumped):
            out.append((start, t - 1))
            start = None
        if active[t] and start is None:
            start = t
    if start is not None:
        out.append((start, len(active) - 1))
    return out


def record(task: LeftTurnTask, scenarios: Scenarios, policy: Any) -> tuple[list[Run], Any]:
    """Play each scenario with ``policy`` and keep every vehicle's trajectory until the episode
    ends; returns one :class:`Run` per scenario and the rollout's result."""
    from safeswitch.evaluation.rollout import rollout

    batch = scenarios.ego_speed.shape[0]
    dt = task.config.episode.dt
    rows: list[tuple[NDArray[Any], ...]] = []
    others: list[tuple[NDArray[Any], ...]] = []
    live = np.ones(batch, dtype=bool)
    ended_at = np.full(batch, -1)

    def keep(state: TaskState) -> None:
        v = state.world.vehicles
        rows.append((v.x.copy(), v.y.copy(), np.arctan2(v.sin_yaw, v.cos_yaw), v.speed.copy()))
        traffic = getattr(state, "traffic", None)
        if traffic is not None:
            others.append((traffic.x.copy(), traffic.y.copy(),
                           np.arctan2(traffic.sin_yaw, traffic.cos_yaw), traffic.speed.copy(),
                           traffic.active.copy()))  # fmt: skip

    keep(task.initial(scenarios))

    def on_tick(state: TaskState, rec: Any, tick: int) -> None:
        keep(state)
        done = live & (rec.terminated | rec.truncated)
        ended_at[done] = tick + 1
        live[:] &= ~done

    result = rollout(task, scenarios, policy, on_tick)
    ended_at[ended_at < 0] = len(rows) - 1
    x, y, yaw, speed = (np.stack([r[i] for r in rows]) for i in range(4))  # [T, B, 2]
    runs = []
    for b in range(batch):
        n = int(ended_at[b]) + 1
        time = dt * np.arange(n, dtype=np.float64)
        ego, north = (
            Track(time, x[:n, b, s], y[:n, b, s], yaw[:n, b, s], speed[:n, b, s]) for s in (0, 1)
        )
        tracks = []
        if others:
            ox, oy, oyaw, ospeed, active = (np.stack([r[i] for r in others]) for i in range(5))
            for slot in range(active.shape[2]):
                for first, last in _appearances(
                    active[:n, b, slot], ox[:n, b, slot], oy[:n, b, slot]
                ):
                    span = slice(first, last + 1)
                    tracks.append(Track(time[span], ox[span, b, slot], oy[span, b, slot],
                                        oyaw[span, b, slot], ospeed[span, b, slot]))  # fmt: skip
            tracks.sort(key=lambda track: float(track.time[0]))
        runs.append(Run(ego, north, tracks))
    return runs, result


def _vehicle(name: str, task: LeftTurnTask) -> Any:
    from scenariogeneration import xosc

    p = task.config.vehicle
    front = p.wheelbase - p.cg_to_rear_axle
    # The reference point is the centre of gravity (the embedded simulator's position): the
    # footprint is centred on it.
    box = xosc.BoundingBox(p.width, p.length, HEIGHT, 0.0, 0.0, HEIGHT / 2)
    track = p.width - 0.3
    return xosc.Vehicle(
        name,
        xosc.VehicleCategory.car,
        box,
        xosc.Axle(p.max_steer_angle, 0.65, track, front, 0.325),
        xosc.Axle(0.0, 0.65, track, -p.cg_to_rear_axle, 0.325),
        max_speed=60.0,
        max_acceleration=p.max_drive_force / p.mass,
        max_deceleration=p.max_brake_force / p.mass,
    )


def write_scenario(
    folder: Path,
    name: str,
    task: LeftTurnTask,
    scenario: Scenarios,
    run: Run,
    description: str,
    traffic: str = "none",
) -> Path:
    """Write scenario ``scenario`` (one row) as ``folder/name.xosc`` with the trajectories of
    ``run`` (the oncoming car's, and in ``traffic`` every other vehicle's: added to the scene
    when it entered, deleted when it left); checked against the schema."""
    from scenariogeneration import xosc

    if scenario.ego_speed.shape != (1,):
        raise OpenScenarioError(
            f"write_scenario takes one scenario, got {scenario.ego_speed.shape}"
        )
    state = task.initial(scenario)
    v = state.world.vehicles
    params = xosc.ParameterDeclarations()
    for osc_name, field_name, _ in PARAMETERS:
        value = float(getattr(scenario, field_name)[0])
        params.add_parameter(xosc.Parameter(osc_name, xosc.ParameterType.double, repr(value)))
    params.add_parameter(xosc.Parameter(TRAFFIC, xosc.ParameterType.string, traffic))
    others = [(f"Car{i + 1}", track) for i, track in enumerate(run.others)]
    entities = xosc.Entities()
    for who in ("Ego", "North", *(car for car, _ in others)):
        entities.add_scenario_object(who, _vehicle(who, task))
    init = xosc.Init()
    step = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0.0)
    for slot, who, speed in ((0, "Ego", "$EgoSpeed"), (1, "North", "$NorthSpeed")):
        yaw = math.atan2(float(v.sin_yaw[0, slot]), float(v.cos_yaw[0, slot]))
        position = xosc.WorldPosition(float(v.x[0, slot]), float(v.y[0, slot]), 0.0, yaw)
        init.add_init_action(who, xosc.TeleportAction(position))
        init.add_init_action(who, xosc.AbsoluteSpeedAction(speed, step))
    route = xosc.Route("EgoRoute")
    ego_route = task.world.routes[0]
    g = task.config.geometry
    for point in (
        ego_route.points[0],
        np.array([-g.box_half_size, g.lane_width / 2]),
        ego_route.points[-1],
    ):
        route.add_waypoint(
            xosc.WorldPosition(float(point[0]), float(point[1]), 0.0), xosc.RouteStrategy.shortest
        )
    every = max(1, round(TRAJECTORY_STEP_S / task.config.episode.dt))

    def follow(who: str, track: Track) -> Any:
        keep = np.unique(np.append(np.arange(0, len(track.time), every), len(track.time) - 1))
        trajectory = xosc.Trajectory(f"{who}Trajectory", False)
        trajectory.add_shape(
            xosc.Polyline(
                [float(t) for t in track.time[keep]],
                [
                    xosc.WorldPosition(float(x), float(y), 0.0, float(h))
                    for x, y, h in zip(track.x[keep], track.y[keep], track.yaw[keep], strict=True)
                ],
            )
        )
        return xosc.FollowTrajectoryAction(
            trajectory, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1.0, 0.0
        )

    half_tick = task.config.episode.dt / 2

    def at(time: float, label: str) -> Any:
        """Fires on the tick at ``time`` (OpenSCENARIO 1.0 has no greaterOrEqual)."""
        threshold = max(time - half_tick, 0.0)
        return xosc.ValueTrigger(
            label, 0.0, xosc.ConditionEdge.none,
            xosc.SimulationTimeCondition(threshold, xosc.Rule.greaterThan),
        )  # fmt: skip

    story = xosc.Story("LeftTurn")
    act = xosc.Act("Drive", at(0.0, "AtStart"))
    vehicles: list[tuple[str, list[tuple[str, Any, float]]]] = [
        ("Ego", [("AssignEgoRoute", xosc.AssignRouteAction(route), 0.0)]),
        ("North", [("FollowRecordedTrajectory", follow("North", run.north), 0.0)]),
    ]
    for car, track in others:
        first, last = float(track.time[0]), float(track.time[-1])
        position = xosc.WorldPosition(float(track.x[0]), float(track.y[0]), 0.0,
                                      float(track.yaw[0]))  # fmt: skip
        steps = [("Enter", xosc.AddEntityAction(car, position), first),
                 ("FollowRecordedTrajectory", follow(car, track), first)]  # fmt: skip
        if last < float(run.ego.time[-1]):  # it left before the episode ended
            steps.append(("Leave", xosc.DeleteEntityAction(car), last))
        vehicles.append((car, steps))
    for who, steps in vehicles:
        maneuver = xosc.Maneuver(f"{who}Maneuver")
        for action_name, action, time in steps:
            event = xosc.Event(f"{who}{action_name}", xosc.Priority.parallel)
            event.add_action(action_name, action)
            event.add_trigger(at(time, f"{who}{action_name}At"))
            maneuver.add_event(event)
        group = xosc.ManeuverGroup(f"{who}Group")
        group.add_actor(who)
        group.add_maneuver(maneuver)
        act.add_maneuver_group(group)
    story.add_act(act)
    horizon = task.config.episode.horizon_ticks * task.config.episode.dt
    stop = xosc.ConditionGroup()
    stop.add_condition(
        xosc.ValueTrigger(
            "Horizon",
            0.0,
            xosc.ConditionEdge.rising,
            xosc.SimulationTimeCondition(horizon, xosc.Rule.greaterThan),
            "stop",
        )
    )
    crash = xosc.ConditionGroup()
    crash.add_condition(
        xosc.EntityTrigger(
            "EgoCollision",
            0.0,
            xosc.ConditionEdge.rising,
            xosc.CollisionCondition(xosc.ObjectType.vehicle),
            "Ego",
            triggeringpoint="stop",
        )
    )
    trigger = xosc.Trigger("stop")
    trigger.add_conditiongroup(stop)
    trigger.add_conditiongroup(crash)
    storyboard = xosc.StoryBoard(init, trigger)
    storyboard.add_story(story)
    scenario_file = xosc.Scenario(
        name,
        "safeswitch",
        params,
        entities,
        storyboard,
        xosc.RoadNetwork(ROAD_FILE),
        xosc.Catalog(),
        osc_minor_version=OSC_MINOR,
    )
    scenario_file.header.description = description
    path = folder / f"{name}.xosc"
    with replacing(path) as tmp:
        scenario_file.write_xml(str(tmp))
        validate(tmp)
    return path


def write_road(folder: Path, task: LeftTurnTask) -> Path:
    """Write the scene's road as ``folder/intersection.xodr``."""
    path = folder / ROAD_FILE
    with replacing(path) as tmp:
        road_network(task).write_xml(str(tmp))
    return path


def _natural(path: Path) -> list[Any]:
    """Sort key: ``random-2`` before ``random-10`` (the order the scenarios were drawn in)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.stem)]


def _files(path: Path) -> list[Path]:
    if path.is_dir():
        files = sorted(path.glob("*.xosc"), key=_natural)
        if not files:
            raise OpenScenarioError(f"{path} holds no .xosc file")
        return files
    if not path.is_file():
        raise OpenScenarioError(f"{path}: no such scenario file or folder")
    return [path]


def read_scenarios(path: str | Path, task: LeftTurnTask) -> tuple[Scenarios, list[str]]:
    """The scenarios of an OpenSCENARIO file (or of every ``.xosc`` in a folder), with their
    names (the files' stems).

    Raises:
        OpenScenarioError: Not schema-valid, a parameter missing or not a number, or a start
            position that does not match this scene's for the parameters read.
    """
    files = _files(Path(path))
    rows: dict[str, list[float]] = {field_name: [] for _, field_name, _ in PARAMETERS}
    starts = []
    for file in files:
        validate(file)
        root = ET.parse(file).getroot()
        declared = {
            p.get("name"): p.get("value")
            for p in root.iterfind("./ParameterDeclarations/ParameterDeclaration")
        }
        traffic = declared.get(TRAFFIC, "none")
        if traffic != "none":
            raise OpenScenarioError(
                f"{file} holds a scene with traffic ({traffic}): its other vehicles replay in "
                "another simulator; safeswitch evaluates traffic from its presets and seeds "
                "(--traffic, --seed)"
            )
        for osc_name, field_name, unit in PARAMETERS:
            text = declared.get(osc_name)
            try:
                value = float(text) if text is not None else math.nan
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise OpenScenarioError(
                    f"{file}: parameter {osc_name} [{unit}] is {text!r}; expected a number (is "
                    "this a scenario written by safeswitch export-scenario?)"
                )
            rows[field_name].append(value)
        starts.append(_start_positions(file, root))
    scenarios = Scenarios(**{k: np.array(v, dtype=np.float64) for k, v in rows.items()})
    placed = task.initial(scenarios).world.vehicles
    for i, (file, start) in enumerate(zip(files, starts, strict=True)):
        for slot, who in enumerate(("Ego", "North")):
            want = np.array([placed.x[i, slot], placed.y[i, slot]])
            if who not in start or np.max(np.abs(start[who] - want)) > POSITION_TOLERANCE:
                raise OpenScenarioError(
                    f"{file}: {who} starts at {start.get(who)}, but this scene places it at "
                    f"{want.round(6).tolist()} for the file's parameters (written for another "
                    "geometry or edited?)"
                )
    return scenarios, [f.stem for f in files]


def _start_positions(file: Path, root: ET.Element) -> dict[str, NDArray[np.float64]]:
    out = {}
    for private in root.iterfind("./Storyboard/Init/Actions/Private"):
        who = private.get("entityRef")
        world = private.find(".//TeleportAction/Position/WorldPosition")
        if who is not None and world is not None:
            out[who] = np.array([float(world.get("x", "nan")), float(world.get("y", "nan"))])
    return out
