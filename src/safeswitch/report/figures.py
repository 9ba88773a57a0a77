"""Figures of single episodes like the paper's Figs. 8–11, top-down animations, and the
controller comparison."""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image

from safeswitch.leftturn.render import render_scene
from safeswitch.leftturn.task import LeftTurnTask, StepRecord, TaskState

#: Record fields kept per tick by :class:`Trace`.
TRACED = (
    "learned_throttle",
    "learned_brake",
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
    "collision",
    "terminated",
    "truncated",
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
    frame_px: int = 480
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
        """Signal ``name`` as ``[B, T]`` (every tick of the rollout, also after an episode
        ended; see :meth:`episode`)."""
        return np.stack(self.signals[name], axis=1)

    def episode(self, name: str, index: int) -> NDArray[np.float64]:
        """Signal ``name`` of episode ``index`` up to and including the tick it ended on (a
        rollout keeps stepping ended episodes; those ticks are not the episode's)."""
        values = self.array(name)[index]
        ended = np.flatnonzero(
            (self.array("terminated")[index] > 0) | (self.array("truncated")[index] > 0)
        )
        return values[: ended[0] + 1] if ended.size else values

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
    """Shade the intervals of ``time`` where ``mask`` holds; a ``label`` names the first only
    (one legend entry however often the interval recurs)."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    dt = time[1] - time[0] if time.size > 1 else 0.02
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(time[start] - dt, time[stop - 1], **style)  # type: ignore[attr-defined]
        style = {**style, "label": None}


def episode_figure(
    trace: Trace,
    episode: int,
    title: str,
    path: Path,
    oracle_speed: NDArray[np.float64] | None = None,
) -> str:
    """The paper's Figs. 8–11 for one episode: control signals, speeds, longitudinal and lateral
    acceleration (comfort limits dashed), the intersection window shaded, ticks on which the
    Safety controller acted shaded red, the moment the ego leaves its conflict zone (dotted) and
    a collision (a red line and marker). Legends sit beside the panels, not on the data. Saved
    as PNG; returns the episode's ending as the figure states it ("COLLISION at 5.30 s",
    "cleared at 7.62 s" or "never cleared the zone")."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    config = trace.task.config
    dt = config.episode.dt

    def sig(name: str) -> NDArray[np.float64]:
        return trace.episode(name, episode)

    time: NDArray[np.float64] = dt * np.arange(1, sig("ego_speed").size + 1, dtype=np.float64)
    window = sig("both_at_intersection") > 0
    safety = sig("safety_active") > 0
    crash = np.flatnonzero(sig("collision") > 0)
    crash_time = float(time[crash[0]]) if crash.size else None
    cleared = np.flatnonzero(sig("ego_cleared") > 0)
    clear_time = float(time[cleared[0]]) if cleared.size else None
    fig, axes = plt.subplots(4, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
    for j, ax in enumerate(axes):
        first = j == 0
        _spans(ax, time, window, color="0.88", label="both at the intersection" if first else None)
        _spans(ax, time, safety, color="#f4a6a6", label="safety action executed" if first else None)
        if clear_time is not None:
            ax.axvline(
                clear_time, color="tab:blue", lw=1.0, ls=":",
                label="ego leaves the conflict zone" if first else None,
            )  # fmt: skip
        if crash_time is not None:
            ax.axvline(crash_time, color="red", lw=2.0, label="COLLISION" if first else None)
    learned = sig("controller") == 0
    # A learned controller with a brake (controllers.learned_brake) proposes brakes of its own:
    # then the executed brake is not only PID_b's.
    learned_brake = np.where(learned, sig("learned_brake"), np.nan)
    brakes = bool(np.nanmax(learned_brake, initial=0.0) > 0.0)
    if learned.any():  # the learned controller proposed the pedals on these ticks
        axes[0].plot(
            time, np.where(learned, sig("learned_throttle"), np.nan), color="tab:green",
            lw=2.5, alpha=0.6, label="learned throttle (proposed)",
        )  # fmt: skip
    if brakes:
        axes[0].plot(
            time, learned_brake, color="tab:purple", lw=2.5, alpha=0.6,
            label="learned brake (proposed)",
        )  # fmt: skip
    axes[0].plot(time, sig("throttle"), color="k", lw=1.0, label="executed throttle")
    axes[0].plot(
        time, sig("brake"), color="tab:red", lw=1.0, ls="--",
        label="executed brake" if brakes else "executed brake (PID_b)",
    )  # fmt: skip
    axes[0].set_ylabel("pedal [0, 1]")
    axes[0].set_ylim(-0.05, 1.05)
    axes[1].plot(time, 3.6 * sig("ego_speed"), color="tab:blue", label="ego")
    axes[1].plot(time, 3.6 * sig("north_speed"), color="tab:orange", label="north car")
    if oracle_speed is not None:
        axes[1].plot(
            time, 3.6 * oracle_speed[1 : time.size + 1], color="0.4", ls="--", label="oracle ego"
        )
    limit = config.controllers.speed_limit_kmh
    tolerated = config.rewards.speed_points_kmh[3]
    axes[1].axhline(limit, color="k", ls="--", lw=0.8, label=f"speed limit {limit:g} km/h")
    axes[1].axhline(
        tolerated, color="0.5", ls=":", lw=0.8, label=f"tolerated speeding {tolerated:g} km/h"
    )
    axes[1].set_ylabel("speed [km/h]")
    limits = config.rewards
    for ax, name, bound, label in (
        (axes[2], "accel_lon", limits.comfort_accel_lon, "a_lon [m/s²]"),
        (axes[3], "accel_lat", limits.comfort_accel_lat, "a_lat [m/s²]"),
    ):
        ax.plot(time, sig(name), color="tab:blue", label=name)
        for sign in (-1, 1):
            ax.axhline(
                sign * bound, color="k", ls="--", lw=0.8,
                label=f"comfort limit ±{bound:g} m/s²" if sign > 0 else None,
            )  # fmt: skip
        ax.set_ylabel(label)
    if crash_time is not None:
        axes[1].plot(
            [crash_time], [3.6 * sig("ego_speed")[crash[0]]], marker="X", color="red", ms=12,
            ls="none", label="collision",
        )  # fmt: skip
    axes[3].set_xlabel("time [s]")
    for ax in axes:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    status = (
        f"COLLISION at {crash_time:.2f} s"
        if crash_time is not None
        else f"cleared at {clear_time:.2f} s"
        if clear_time is not None
        else "never cleared the zone"
    )
    fig.suptitle(f"{title}\n{status}", color="red" if crash_time is not None else "k")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return status


@dataclass
class ComparisonRow:
    """One controller's episodes on the comparison's random scenarios.

    Attributes:
        label: What it is.
        time_to_clear: Per scenario [s] (NaN: never cleared) ``[N]``.
        collision: Per scenario ``[N]``.
        outcome: Per scenario: 1 cut, 2 yield, 0 never cleared ``[N]``.
        efficiency: Per scenario (oracle time / time) ``[N]``.
        lost_control: Per scenario: the episode ended with the ego off its lane ``[N]``.
        speeding: Per scenario: the ego drove faster than the tolerated speed ``[N]``.
    """

    label: str
    time_to_clear: NDArray[np.float64]
    collision: NDArray[np.bool_]
    outcome: NDArray[np.int8]
    efficiency: NDArray[np.float64]
    lost_control: NDArray[np.bool_]
    speeding: NDArray[np.bool_]


def comparison_figure(
    rows: list[ComparisonRow],
    oracle_time: NDArray[np.float64],
    offsets: NDArray[np.float64],
    horizon_s: float,
    path: Path,
) -> None:
    """Small multiples, one panel per controller: its time to clear against the north car's
    arrival offset (cuts blue, yields orange), the oracle's in grey on every panel, episodes
    that never cleared as triangles at the top, speeding episodes ringed, collisions and losses
    of control as red crosses; each title gives the mean efficiency, the failures and the
    speeding episodes. Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = 4
    lines = -(-len(rows) // columns)
    fig, axes = plt.subplots(
        lines, columns, figsize=(15, 3.6 * lines), sharex=True, sharey=True,
        constrained_layout=True, squeeze=False,
    )  # fmt: skip
    top = horizon_s + 0.4
    for ax, row in zip(axes.flat, rows, strict=False):
        ax.scatter(offsets, oracle_time, s=3, color="0.75", label="oracle (the limit)")
        never = ~np.isfinite(row.time_to_clear)
        shown = np.where(never, top, row.time_to_clear)
        failed = row.collision | row.lost_control
        for code, colour, name in ((1, "tab:blue", "crossed first (cut)"),
                                   (2, "tab:orange", "crossed after (yield)")):  # fmt: skip
            pick = (row.outcome == code) & ~never & ~failed
            if pick.any():
                ax.scatter(offsets[pick], shown[pick], s=5, color=colour, label=name)
        pick = never & ~failed
        if pick.any():
            ax.scatter(
                offsets[pick], shown[pick], s=14, marker="^", color="tab:purple",
                label="never cleared",
            )  # fmt: skip
        if row.speeding.any():  # ringed: the episode drove above the tolerated speed
            pick = row.speeding & ~failed
            ax.scatter(
                offsets[pick], shown[pick], s=22, facecolors="none", edgecolors="k", lw=0.6,
                label=f"speeding ({int(row.speeding.sum())})", zorder=4,
            )  # fmt: skip
        lost = row.lost_control & ~row.collision
        for mask, marker, name in ((row.collision, "x", "collision"),
                                   (lost, "+", "lost control")):  # fmt: skip
            if mask.any():
                ax.scatter(
                    offsets[mask], shown[mask], s=40, marker=marker, color="red", lw=1.5,
                    label=f"{name} ({int(mask.sum())})", zorder=5,
                )  # fmt: skip
        mean = float(np.nanmean(row.efficiency)) if np.isfinite(row.efficiency).any() else 0.0
        ax.set_title(
            f"{row.label}\nefficiency {mean:.3f}, {int(failed.sum())} failures, "
            f"{int(row.speeding.sum())} speeding",
            fontsize=9,
            color="red" if failed.any() or row.speeding.any() else "k",
        )
        ax.set_ylim(0, top + 0.6)
        ax.legend(fontsize=6, loc="lower right", markerscale=2, framealpha=0.8)
    for ax in axes.flat[len(rows) :]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("north arrival − ego arrival at cruise [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel(f"time to clear [s]\n(▲ at top: never within {horizon_s:g} s)")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def traffic_figure(rows: list[dict[str, Any]], presets: tuple[str, ...], path: Path) -> None:
    """Time to clear against traffic density: per controller, the share of episodes that
    cleared the conflict zone and the mean time to clear of those that did, one point per
    preset (lightest first); collisions are written next to the points. Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    x = np.arange(len(presets))
    series: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        label = row["controller"] + (f" / {row['switching']}" if row["switching"] else "")
        series.setdefault(label, []).append(row)
    for label, points in series.items():
        by = {p["preset"]: p for p in points}
        cleared = [by[p]["cleared_episodes"] / by[p]["episodes"] for p in presets]
        mean = [by[p]["mean_time_to_clear_s"] or np.nan for p in presets]
        failed = [by[p].get("failures", by[p]["collisions"]) for p in presets]
        if sum(failed):  # named in the legend (a label on the plot would cross the lines)
            where = (f"{n} ({p})" for n, p in zip(failed, presets, strict=True) if n)
            label += f" — failures: {', '.join(where)}"
        (line,) = left.plot(x, cleared, marker="o", label=label)
        right.plot(x, mean, marker="o", color=line.get_color(), label=label)
        crashed = np.flatnonzero(failed)
        if crashed.size:  # and marked on its points: a red cross
            left.scatter(x[crashed], np.asarray(cleared)[crashed], marker="x", s=70, color="red",
                         zorder=5, linewidths=2)  # fmt: skip
    for ax, title in ((left, "episodes that cleared the conflict zone"),
                      (right, "mean time to clear (episodes that cleared) [s]")):  # fmt: skip
        ax.set_xticks(x, presets)
        ax.set_xlabel("traffic (lightest to densest; test: the densest, least courteous)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    left.set_ylim(0, 1.05)
    left.yaxis.set_major_formatter(matplotlib.ticker.PercentFormatter(1.0))
    handles, labels = right.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def adaptation_figure(summaries: list[dict[str, Any]] | dict[str, Any], path: Path) -> None:
    """Learning after deployment (``safeswitch adapt``): per shift, the share of episodes with
    a safety action and the efficiency against deployment episodes — the deployed episodes of
    each block and the deterministic policy on held-out scenarios after it, beside the frozen
    policy's on the same held-out scenarios (dashed); a star marks the selected policy (the one
    adapting hands back), an open marker a block deployed with learning paused (settled), a red
    cross a block with a failure. Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [summaries] if isinstance(summaries, dict) else summaries
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.4), layout="constrained")
    for run in runs:
        blocks = run["blocks"]
        x = np.cumsum([b["episodes"] for b in blocks])
        label = run.get("name") or ", ".join(run["shift"]) or "no shift"
        safety = [b["safety_activation_episodes"] / b["episodes"] for b in blocks]
        held = [b["held_out"]["safety_activation_episodes"] / b["held_out"]["episodes"]
                for b in blocks]  # fmt: skip
        frozen = run["frozen_held_out"]
        (line,) = left.plot(x, safety, marker="o", label=f"{label}: deployed")
        color = line.get_color()
        left.plot(x, held, marker="s", ls=":", color=color, label=f"{label}: held out")
        left.axhline(frozen["safety_activation_episodes"] / frozen["episodes"], color=color,
                     ls="--", lw=1, label=f"{label}: frozen policy")  # fmt: skip
        deployed_efficiency = [b.get("mean_efficiency", np.nan) for b in blocks]
        right.plot(x, deployed_efficiency, marker="o", color=color)
        settled = np.array([b.get("settled", False) for b in blocks], dtype=bool)
        if settled.any():  # open markers: the selected policy deployed, learning paused
            hollow = dict(marker="o", facecolors="white", edgecolors=color, zorder=4)
            left.scatter(x[settled], np.asarray(safety)[settled], **hollow)
            right.scatter(x[settled], np.asarray(deployed_efficiency)[settled], **hollow)
        right.plot(x, [b["held_out"]["mean_efficiency"] for b in blocks], marker="s", ls=":",
                   color=color)  # fmt: skip
        right.axhline(frozen["mean_efficiency"], color=color, ls="--", lw=1)
        chosen = run.get("selected_block")
        if chosen is not None:  # the policy adapting hands back (0: the frozen one)
            at = 0 if chosen == 0 else x[chosen - 1]
            point = frozen if chosen == 0 else blocks[chosen - 1]["held_out"]
            star = dict(marker="*", s=170, color=color, edgecolors="black", zorder=6)
            left.scatter([at], [point["safety_activation_episodes"] / point["episodes"]],
                         label=f"{label}: selected", **star)  # fmt: skip
            right.scatter([at], [point["mean_efficiency"]], **star)
        failed = np.array([b["failures"] for b in blocks]) > 0
        if failed.any():
            left.scatter(x[failed], np.asarray(safety)[failed], marker="x", s=80, color="red",
                         zorder=5, linewidths=2, label="a block with a failure")  # fmt: skip
    fig.suptitle(f"learning after deployment under {runs[0]['switching']}\n(dashed: the frozen "
                 "policy on the held-out scenarios; open markers: learning paused, the selected "
                 "policy deployed)", fontsize=10)  # fmt: skip
    left.set_title("episodes with a safety action", fontsize=10)
    left.yaxis.set_major_formatter(matplotlib.ticker.PercentFormatter(1.0))
    right.set_title("efficiency against the oracle", fontsize=10)
    for ax in (left, right):
        ax.set_xlabel("deployment episodes")
        ax.grid(alpha=0.3)
    handles, labels = left.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


#: Axis labels of the perception sweeps (by sweep name).
PERCEPTION_AXES = {
    "together": "level × (1 m, 1 m/s, 0.2 s)",
    "position_error_m": "position error bound [m]",
    "speed_error_mps": "speed error bound [m/s]",
    "latency_s": "latency [s]",
    "dropout_max_s": "longest miss [s] (5 % per tick)",
    "sight_distance_m": "sight distance [m]",
}


def perception_figure(rows: list[dict[str, Any]], path: Path, scene: str = "") -> None:
    """Perception errors (:mod:`safeswitch.app.perception_study`): per sweep (a column),
    collisions per 1,000 episodes (top) and efficiency against the oracle (bottom) against the
    error level, one colour per controller, solid for adversarial errors and dashed for random
    ones; ``scene`` names the scene in the title. Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweeps = list(dict.fromkeys(r["sweep"] for r in rows))
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    width = max(9.0, 3.6 * len(sweeps) + 1)
    fig, axes = plt.subplots(2, len(sweeps), figsize=(width, 6.8), layout="constrained",
                             squeeze=False)  # fmt: skip
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for col, sweep in enumerate(sweeps):
        top, bottom = axes[0, col], axes[1, col]
        levels = sorted({r["level"] for r in rows if r["sweep"] == sweep})
        # an unlimited sight distance (level 0) sits to the right of the longest one
        unlimited = max(levels) * 1.4 if sweep == "sight_distance_m" and levels[0] == 0 else None

        def place(level: float, unlimited: float | None = unlimited) -> float:
            return unlimited if unlimited is not None and level == 0 else level

        for k, controller in enumerate(controllers):
            for errors, style in (("adversarial", "-"), ("random", "--")):
                cell = sorted((r for r in rows if r["sweep"] == sweep
                               and r["controller"] == controller and r["errors"] == errors),
                              key=lambda r: r["level"])  # fmt: skip
                if not cell:
                    continue
                cell.sort(key=lambda r: place(r["level"]))
                x = [place(r["level"]) for r in cell]
                rate = [1000.0 * r["failures"] / r["episodes"] for r in cell]
                label = f"{controller} ({errors})"
                top.plot(x, rate, style, marker="o", color=colours[k], label=label)
                bottom.plot(x, [r["mean_efficiency"] for r in cell], style, marker="o",
                            color=colours[k])  # fmt: skip
        top.set_title(sweep.replace("_", " "), fontsize=10)
        top.set_ylabel("failures per 1,000 episodes" if col == 0 else "")
        bottom.set_ylabel("efficiency against the oracle" if col == 0 else "")
        bottom.set_xlabel(PERCEPTION_AXES.get(sweep, sweep))
        if unlimited is not None:
            ticks = [place(x) for x in levels]
            names = ["none" if x == 0 else f"{x:g}" for x in levels]
            for ax in (top, bottom):
                ax.set_xticks(ticks, names)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8)
    where = f" {scene}" if scene else ""
    fig.suptitle(f"perception errors{where}: failures (on the truth) and efficiency\n"
                 "solid: adversarial errors, dashed: random errors", fontsize=10)  # fmt: skip
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


def falsification_figure(
    runs: list[tuple[str, NDArray[np.float64], NDArray[np.float64]]],
    ranges: NDArray[np.float64],
    failure: str,
    path: Path,
) -> None:
    """Where the failures are: every simulated scenario in the (arrival offset, north speed)
    plane, coloured by its smallest footprint separation, failures as red crosses; one panel
    for uniform random sampling and one for the cross-entropy search. ``runs``: (method,
    normalised parameters ``[N, 4]``, outcome ``[N, 3]`` = separation, collision, safety ticks).
    Saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = ("random", "cross-entropy")
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharex=True, sharey=True,
                             constrained_layout=True)  # fmt: skip
    span = ranges[:, 1] - ranges[:, 0]
    scatter = None
    for ax, method in zip(axes, methods, strict=True):
        units = np.concatenate([u for m, u, _ in runs if m == method])
        outcome = np.concatenate([o for m, _, o in runs if m == method])
        values = ranges[:, 0] + units * span
        failed = outcome[:, 1] > 0 if failure == "collision" else outcome[:, 2] > 0
        scatter = ax.scatter(
            values[:, 3], values[:, 2], c=np.clip(outcome[:, 0], 0, 5), s=4, cmap="viridis",
            vmin=0, vmax=5,
        )  # fmt: skip
        ax.scatter(values[failed, 3], values[failed, 2], marker="x", s=30, color="red",
                   label=f"{failure} ({int(failed.sum())} of {failed.size})")  # fmt: skip
        ax.set_title(f"{method}: {1000 * failed.mean():.1f} failures per 1,000 episodes")
        ax.set_xlabel("north arrival − ego arrival at cruise [s]")
        ax.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("north car speed [km/h]")
    if scatter is not None:
        fig.colorbar(scatter, ax=axes, label="smallest separation [m] (clipped at 5)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
