"""Top-down pictures of the scene (``render_mode="rgb_array"``), drawn with Pillow."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont

from safeswitch.leftturn.task import CONTROLLERS, LeftTurnTask, StepRecord, TaskState

SIZE_PX = 480
VIEW_M = 90.0  # width of the square view, centred on the intersection [m]
COLOURS = {
    "grass": (196, 214, 180),
    "road": (88, 88, 92),
    "marking": (235, 235, 235),
    "route": (120, 170, 255),
    "zone": (230, 120, 100),
    "ego": (40, 110, 230),
    "north": (240, 150, 30),
    "other": (175, 175, 180),
    "rude": (150, 60, 140),
    "crash": (220, 20, 20),
    "text": (20, 20, 20),
}


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's bundled font at ``size`` px (its bitmap font where FreeType is missing)."""
    try:
        return ImageFont.load_default(size=size)
    except (OSError, TypeError):  # pragma: no cover - Pillow without FreeType
        return ImageFont.load_default()


def _legend(
    draw: ImageDraw.ImageDraw,
    font: ImageFont.FreeTypeFont | ImageFont.ImageFont,
    traffic: bool = False,
) -> None:
    """What the colours mean, in the bottom-left corner."""
    items: tuple[tuple[str, str, str], ...] = (
        ("ego (automated)", "ego", "box"),
        ("north car (never yields)", "north", "box"),
    )
    if traffic:
        items += (("other (gives way)", "other", "box"), ("other (never yields)", "rude", "box"))
    items += (("ego route", "route", "line"), ("ego conflict zone", "zone", "line"))
    top = SIZE_PX - 8 - 18 * len(items)
    draw.rectangle((4, top - 4, 206, SIZE_PX - 4), fill=(255, 255, 255))
    for j, (label, colour, kind) in enumerate(items):
        y = top + 18 * j
        if kind == "box":
            draw.rectangle((10, y + 3, 28, y + 13), fill=COLOURS[colour], outline=COLOURS["text"])
        else:
            draw.line((10, y + 8, 28, y + 8), fill=COLOURS[colour], width=4)
        draw.text((36, y), label, fill=COLOURS["text"], font=font)


def _px(xy: NDArray[np.float64]) -> list[tuple[float, float]]:
    scale = SIZE_PX / VIEW_M
    return [(SIZE_PX / 2 + x * scale, SIZE_PX / 2 - y * scale) for x, y in np.atleast_2d(xy)]


def _rectangle(
    x: float, y: float, c: float, s: float, length: float, width: float
) -> NDArray[np.float64]:
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    rotation = np.array([[c, -s], [s, c]])
    return corners @ rotation.T + [x, y]


def render_scene(
    task: LeftTurnTask, state: TaskState, index: int, record: StepRecord | None = None
) -> NDArray[np.uint8]:
    """A ``[480, 480, 3]`` picture of episode ``index``: roads, the ego's route and conflict
    zone, both cars (outlined red when they collide), a status line (time, speeds, who drives)
    and a legend."""
    g = task.config.geometry
    image = Image.new("RGB", (SIZE_PX, SIZE_PX), COLOURS["grass"])
    draw = ImageDraw.Draw(image)
    far, half_road = VIEW_M, g.lane_width
    for box in (
        ((-half_road, -far), (half_road, far)),
        ((-far, -half_road), (far, half_road)),
        ((-g.box_half_size, -g.box_half_size), (g.box_half_size, g.box_half_size)),
    ):
        (x0, y1), (x1, y0) = _px(np.array(box))
        draw.rectangle((x0, y0, x1, y1), fill=COLOURS["road"])
    for sign in (-1, 1):  # centre lines and stop lines
        for a, b in (
            ((0, sign * g.box_half_size), (0, sign * far)),
            ((sign * g.box_half_size, 0), (sign * far, 0)),
        ):
            draw.line(_px(np.array([a, b])), fill=COLOURS["marking"], width=1)
    route = task.world.routes[0]
    draw.line(_px(route.points), fill=COLOURS["route"], width=2)
    zone = route.points[
        int(task.conflict.zone_a[0] / route.spacing) : int(task.conflict.zone_a[1] / route.spacing)
        + 1
    ]
    draw.line(_px(zone), fill=COLOURS["zone"], width=4)
    ((cx, cy),) = _px(task.conflict.point)
    draw.ellipse((cx - 3, cy - 3, cx + 3, cy + 3), fill=COLOURS["crash"])

    v, p = state.world.vehicles, task.config.vehicle
    crashed = record is not None and bool(record.collision[index])
    traffic = getattr(state, "traffic", None)
    if traffic is not None:  # the other vehicles, under the paper's two
        for i in np.flatnonzero(traffic.active[index]):
            corners = _rectangle(
                traffic.x[index, i], traffic.y[index, i], traffic.cos_yaw[index, i],
                traffic.sin_yaw[index, i], p.length, p.width,
            )  # fmt: skip
            colour = "other" if traffic.yields[index, i] else "rude"
            draw.polygon(_px(corners), fill=COLOURS[colour], outline=COLOURS["text"])
    for slot, name in ((1, "north"), (0, "ego")):
        corners = _rectangle(
            v.x[index, slot],
            v.y[index, slot],
            v.cos_yaw[index, slot],
            v.sin_yaw[index, slot],
            p.length,
            p.width,
        )
        draw.polygon(
            _px(corners),
            fill=COLOURS[name],
            outline=COLOURS["crash"] if crashed else COLOURS["text"],
        )

    font = _font(15)
    t = state.tick[index] * task.config.episode.dt
    status = (
        f"t = {t:5.2f} s   ego {v.speed[index, 0] * 3.6:4.1f} km/h   "
        f"north {v.speed[index, 1] * 3.6:4.1f} km/h"
    )
    draw.rectangle((0, 0, SIZE_PX, 22), fill=(255, 255, 255))
    draw.text((6, 3), status, fill=COLOURS["text"], font=font)
    if record is not None:
        who = CONTROLLERS[int(record.controller[index])]
        line = f"driving: {who}" + ("   COLLISION" if crashed else "")
        draw.rectangle((0, 22, SIZE_PX, 42), fill=(255, 255, 255))
        draw.text(
            (6, 24),
            line,
            fill=COLOURS["crash"] if crashed or who == "safety" else COLOURS["text"],
            font=font,
        )
    _legend(draw, _font(13), traffic is not None)
    return np.asarray(image, dtype=np.uint8)
