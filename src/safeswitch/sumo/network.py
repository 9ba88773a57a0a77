"""The intersection of :class:`~safeswitch.sim.params.IntersectionGeometry` as a SUMO network.

Generated at run time with SUMO's ``netconvert`` from a plain description (nodes and edges), not
checked in: one lane each way per leg, lanes ``lane_width`` wide, the junction a square of
``box_half_size`` around the centre (so the stop lines are where ours are), approaches
``approach_length`` long, coordinates kept as ours (``--offset.disable-normalization``). The
north–south road has the right of way (edge priority), as in :mod:`safeswitch.sim.network`.
The network is built once per geometry and SUMO version and cached (written to a temporary
folder, then renamed into place).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from safeswitch.sim.params import IntersectionGeometry
from safeswitch.sim.road import LEG_DIRECTIONS
from safeswitch.sim.streams import TURN_LATERAL_ACCEL

#: Speed limit on every edge [m/s] (50 km/h; the vehicles' own top speeds are lower).
EDGE_SPEED = 50.0 / 3.6
#: Edge priorities: the main road over the minor road.
PRIORITY = {"north": 2, "south": 2, "east": 1, "west": 1}


class SumoMissingError(RuntimeError):
    """SUMO is not installed (the message says how to install it)."""


def sumo_home() -> Path:
    """SUMO's installation folder (from the ``eclipse-sumo`` package).

    Raises:
        SumoMissingError: It is not installed.
    """
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError as exc:
        raise SumoMissingError(
            "SUMO is not installed: pip install 'safeswitch[sumo]' (eclipse-sumo, libsumo, sumolib)"
        ) from exc
    return Path(sumo.SUMO_HOME)


def binary(name: str) -> Path:
    """A SUMO program (``netconvert``, ``sumo``)."""
    path = sumo_home() / "bin" / name
    if not path.is_file():
        raise SumoMissingError(f"SUMO's {name} is missing from {path.parent}")
    return path


def edge_id(leg: str, inbound: bool) -> str:
    """The edge of ``leg`` towards the junction (``inbound``) or away from it."""
    return f"{leg}_{'in' if inbound else 'out'}"


def plain_description(geometry: IntersectionGeometry) -> tuple[str, str]:
    """The nodes and edges files of the network, as XML text."""
    g = geometry
    end = g.box_half_size + g.approach_length
    h = g.box_half_size
    nodes = [
        f'  <node id="centre" x="0" y="0" type="priority" '
        f'shape="{-h},{-h} {h},{-h} {h},{h} {-h},{h}"/>'
    ]
    edges = []
    for leg, (dx, dy) in LEG_DIRECTIONS.items():
        nodes.append(f'  <node id="{leg}" x="{dx * end:g}" y="{dy * end:g}" type="dead_end"/>')
        for inbound in (True, False):
            a, b = (leg, "centre") if inbound else ("centre", leg)
            edges.append(
                f'  <edge id="{edge_id(leg, inbound)}" from="{a}" to="{b}" numLanes="1" '
                f'speed="{EDGE_SPEED:.4f}" priority="{PRIORITY[leg]}" width="{g.lane_width:g}"/>'
            )
    return (
        "<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n",
        "<edges>\n" + "\n".join(edges) + "\n</edges>\n",
    )


def cache_folder() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "safeswitch" / "sumo"


def network_file(geometry: IntersectionGeometry | None = None) -> Path:
    """The ``.net.xml`` of ``geometry`` (built with ``netconvert`` on first use, cached).

    Raises:
        SumoMissingError: SUMO is not installed.
        RuntimeError: ``netconvert`` failed (its output quoted).
    """
    geometry = geometry or IntersectionGeometry()
    nodes, edges = plain_description(geometry)
    version = sumo_home().name + str(binary("netconvert").stat().st_size)
    # Turning speeds inside the junction: SUMO limits each internal lane's speed so that
    # v²|κ| stays within the embedded drivers' turning limit (SUMO's default is 5.5 m/s²); with
    # SUMO's emergency deceleration of 8 m/s² (plant.py) every vehicle then stays within the
    # tyres' friction circle, √(8² + 3²) = 8.5 < μ·g = 8.8 m/s².
    options = ["--junctions.limit-turn-speed", str(TURN_LATERAL_ACCEL)]
    key = hashlib.sha256((nodes + edges + version + " ".join(options)).encode()).hexdigest()[:16]
    target = cache_folder() / key / "intersection.net.xml"
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        folder = Path(tmp)
        (folder / "intersection.nod.xml").write_text(nodes, encoding="utf-8")
        (folder / "intersection.edg.xml").write_text(edges, encoding="utf-8")
        out = folder / "intersection.net.xml"
        done = subprocess.run(
            [
                str(binary("netconvert")),
                "--node-files", str(folder / "intersection.nod.xml"),
                "--edge-files", str(folder / "intersection.edg.xml"),
                "--output-file", str(out),
                "--offset.disable-normalization", "true",
                "--no-turnarounds", "true",
                "--no-warnings", "true",
                *options,
            ],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        if done.returncode != 0 or not out.is_file():
            raise RuntimeError(f"netconvert failed ({done.returncode}): {done.stderr.strip()}")
        os.replace(out, target)
    return target


def remove_cache() -> None:
    """Delete every cached network."""
    shutil.rmtree(cache_folder(), ignore_errors=True)
