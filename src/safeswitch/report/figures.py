"""Figures of single episodes like the paper's Figs. 8–11, top-down animations, and the
controller comparison."""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from PIL import Image

from safeswitch.leftturn.render import render_scene
from safeswitch.leftturn.task import LeftTurnTask, StepRecord, TaskState

#: Record fields kept per tick by :class:`Trace`.
TRACED = (
    "learned_throttle",
    "safety_brake",
    "throttle",
    "brake",
    "ego_speed",
    "north_speed",
    "accel_lon",
    "accel_lat",
    "safety_active",
    "both_at_intersection",
    "ego_cleared",
    "controller",
)


@dataclass
class Trace:
    """Collects, tick by tick, the signals of every episode of a rollout (pass :meth:`on_tick`
    to :func:`~safeswitch.evaluation.rollout.rollout`), and optionally animation frames.

    Args:
        task: The task being rolled out.
        animate: Episode indices to draw a frame of every ``frame_every`` ticks.
        frame_every: Ticks between frames.
        frame_px: Side of each frame [px].
    """

    task: LeftTurnTask
    animate: tuple[int, ...] = ()
    frame_every: int = 6
    frame_px: int = 360
    signals: dict[str, list[NDArray[np.float64]]] = field(default_factory=dict)
    frames: dict[int, list[Image.Image]] = field(default_factory=dict)

    def on_tick(self, state: TaskState, record: StepRecord, tick: int) -> None:
        for name in TRACED:
            self.signals.setdefault(name, []).append(np.asarray(getattr(record, name), float))
        if tick % self.frame_every == 0:
            for i in self.animate:
                picture = Image.fromarray(render_scene(self.task, state, i, record))
                frame = picture.resize((self.frame_px, self.frame_px), Image.Resampling.LANCZOS)
                self.frames.setdefault(i, []).append(frame)

    def array(self, name: str) -> NDArray[np.float64]:
        """Signal ``name`` as ``[B, T]``."""
        return np.stack(self.signals[name], axis=1)

    def gif(self, episode: int) -> bytes:
        """The episode's animation as a GIF (played at twice the real speed)."""
        frames = self.frames[episode]
        duration = int(1000 * self.frame_every * self.task.config.episode.dt / 2)
        buffer = io.BytesIO()
        frames[0].save(
            buffer,
            format="GIF",
            save_all=True,
            append_images=frames[1:],
            duration=duration,
            loop=0,
            optimize=True,
        )
        return buffer.getvalue()


def _spans(ax: object, time: NDArray[np.float64], mask: NDArray[np.bool_], **style: object) -> None:
    """Shade the intervals of ``time`` where ``mask`` holds."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    dt = time[1] - time[0] if time.size > 1 else 0.02
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(time[start] - dt, time[stop - 1], **style)  # type: ignore[attr-defined]


def episode_figure(
    trace: Trace,
    episode: int,
    title: str,
    path: Path,
    oracle_speed: NDArray[np.float64] | None = None,
) -> None:
    """The paper's Figs. 8–11 for one episode: control signals, speeds, longitudinal and lateral
    acceleration (comfort limits dashed), the intersection window shaded, ticks on which the
    Safety controller acted shaded red. Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    config = trace.task.config
    dt = config.episode.dt

    def sig(name: str) -> NDArray[np.float64]:
        return trace.array(name)[episode]

    time: NDArray[np.float64] = dt * np.arange(1, sig("ego_speed").size + 1, dtype=np.float64)
    window = sig("both_at_intersection") > 0
    safety = sig("safety_active") > 0
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True, constrained_layout=True)
    for j, ax in enumerate(axes):
        first = j == 0
        _spans(ax, time, window, color="0.88", label="both at the intersection" if first else None)
        _spans(ax, time, safety, color="#f4a6a6", label="safety action executed" if first else None)
        cleared = np.flatnonzero(sig("ego_cleared") > 0)
        if cleared.size:
            ax.axvline(time[cleared[0]], color="tab:blue", lw=0.8, ls=":")
    if (sig("controller") == 0).any():  # the learned controller proposed the pedals
        axes[0].plot(time, sig("learned_throttle"), color="tab:green", label="learned throttle")
    axes[0].plot(time, sig("throttle"), color="k", lw=0.8, label="executed throttle")
    axes[0].plot(time, sig("brake"), color="tab:red", lw=0.8, label="executed brake (PID_b)")
    axes[0].set_ylabel("pedal [0, 1]")
    axes[0].set_ylim(-0.05, 1.05)
    axes[1].plot(time, 3.6 * sig("ego_speed"), color="tab:blue", label="ego")
    axes[1].plot(time, 3.6 * sig("north_speed"), color="tab:orange", label="north car")
    if oracle_speed is not None:
        axes[1].plot(
            time, 3.6 * oracle_speed[1 : time.size + 1], color="0.4", ls="--", label="oracle ego"
        )
    axes[1].axhline(config.controllers.speed_limit_kmh, color="k", ls="--", lw=0.8)
    axes[1].set_ylabel("speed [km/h]")
    limits = config.rewards
    for ax, name, limit, label in (
        (axes[2], "accel_lon", limits.comfort_accel_lon, "a_lon [m/s²]"),
        (axes[3], "accel_lat", limits.comfort_accel_lat, "a_lat [m/s²]"),
    ):
        ax.plot(time, sig(name), color="tab:blue")
        for sign in (-1, 1):
            ax.axhline(sign * limit, color="k", ls="--", lw=0.8)
        ax.set_ylabel(label)
    axes[3].set_xlabel("time [s] (dotted: the ego leaves the conflict zone)")
    axes[0].legend(loc="upper right", fontsize=7, ncol=2)
    axes[1].legend(loc="lower left", fontsize=7, ncol=3)
    fig.suptitle(title)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def comparison_figure(
    rows: list[tuple[str, NDArray[np.float64], NDArray[np.float64]]],
    oracle_time: NDArray[np.float64],
    offsets: NDArray[np.float64],
    path: Path,
) -> None:
    """Time to clear against the north car's arrival offset for each controller, the oracle as
    the lower envelope. ``rows``: (label, time to clear ``[N]``, efficiency ``[N]``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for label, time, _ in rows:
        left.scatter(offsets, time, s=4, alpha=0.5, label=label)
    left.scatter(offsets, oracle_time, s=3, color="k", label="oracle (the limit)")
    left.set_xlabel("north arrival − ego arrival at cruise [s]")
    left.set_ylabel("time to clear the conflict zone [s]\n(missing: never within 12 s)")
    left.legend(fontsize=7, markerscale=3)
    means = [float(np.nanmean(eff)) for _, _, eff in rows]
    right.barh([label for label, _, _ in rows], means, color="tab:blue")
    right.axvline(1.0, color="k", lw=0.8)
    right.set_xlim(0, max(1.05, max(means, default=1.0) + 0.1))
    right.set_xlabel("mean oracle time / controller time")
    for y, value in enumerate(means):
        right.text(value + 0.01, y, f"{value:.2f}", va="center", fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def frames_strip(trace: Trace, episode: int, count: int = 6) -> Image.Image:
    """A strip of ``count`` animation frames, evenly spaced (for the Markdown report)."""
    frames = trace.frames[episode]
    picks = np.linspace(0, len(frames) - 1, count).round().astype(int)
    width, height = frames[0].size
    strip = Image.new("RGB", (width * count, height))
    for j, k in enumerate(picks):
        strip.paste(frames[k], (j * width, 0))
    return strip
