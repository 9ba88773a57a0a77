"""Training curves like the paper's Fig. 5, from a run's ``progress.csv`` — the left turn's
(its reward terms) or any other plant's (return, the Safety controller's share of steps, the
failures the plant declares)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.ticker import FuncFormatter, MaxNLocator

from safeswitch.io import replacing

#: The paper's six panels (a)–(f), then two of ours: when the policy starts to cut in front,
#: and how often the Safety controller still acts.
PANELS = (
    ("return", "(a) cumulative reward (per episode)"),
    ("adas", "(b) ADAS"),
    ("lka", "(c) lane keeping"),
    ("speed", "(d) velocity"),
    ("accel_lon", "(e) longitudinal acceleration"),
    ("accel_lat", "(f) lateral acceleration"),
    ("cut_rate", "(g) episodes the ego crosses first (ours)"),
    ("activation_episode_rate", "(h) episodes with a safety action (ours)"),
)


def steps_label(steps: float) -> str:
    """A tick label for a number of time steps: ``0``, ``400k``, ``1.2M``."""
    if abs(steps) >= 1e6:
        return f"{steps / 1e6:.3g}M"
    if abs(steps) >= 1e3:
        return f"{steps / 1e3:.3g}k"
    return f"{steps:.0f}"


#: Any other plant's panels (``training.generic``'s log): its return, how often the Safety
#: controller acted, and the failures it declares.
PLANT_PANELS = (
    ("return", "(a) return (per episode)"),
    ("activation_rate", "(b) share of steps with the Safety controller"),
    ("failure_rate", "(c) share of episodes that failed (as the plant declares)"),
)


def collision_steps(progress_csv: str | Path) -> list[tuple[int, int]]:
    """``(time step, collisions)`` of every rollout in which training collided — for any other
    plant, failed —, from the log's running total (empty for a log that does not record it)."""
    with open(progress_csv, encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    return _collision_steps(rows, _total_key(rows))


def _total_key(rows: list[dict[str, str]]) -> str:
    """The running total of failures a log keeps: the left turn's collisions or any other
    plant's declared failures."""
    return "failures_total" if rows and "failures_total" in rows[0] else "collisions_total"


def _collision_steps(rows: list[dict[str, str]], key: str) -> list[tuple[int, int]]:
    out, before = [], 0
    for row in rows:
        total = int(float(row.get(key) or before))
        if total > before:
            out.append((int(row["timesteps"]), total - before))
        before = total
    return out


#: The colour of the line at the policy a run kept (tab:green; no curve is drawn in it).
SELECTED_COLOR = "#2ca02c"


def training_curves(
    progress_csv: str | Path, out_png: str | Path, title: str = "", selected: int | None = None
) -> None:
    """The left turn's log: eight panels against timesteps — the episode return and each
    reward term's per-episode sum (not normalised; the paper's Fig. 5), then the share of
    episodes that cut in front and the share with a safety action, each averaged over a
    rollout's finished episodes. Any other plant's log: its return, the share of steps with
    the Safety controller and the share of episodes that failed. Every rollout in which
    training collided (failed) is marked along the return panel's foot (a red tick) and the
    total is in the title. ``selected``: the time step of the policy the run kept (chosen on
    its validation scenarios), a dashed green line across every panel — the curves go on to
    the end of the run, the policy does not."""
    with open(progress_csv, encoding="utf-8") as handle:
        logged = list(csv.DictReader(handle))
    key = _total_key(logged)
    plant = key == "failures_total"
    # every rollout counts its collisions, those that finished no episode too
    collisions = _collision_steps(logged, key)
    rows = [r for r in logged if r["return"] != ""]
    if not rows:
        raise ValueError(f"{progress_csv} has no finished episodes yet")
    steps = [int(r["timesteps"]) for r in rows]
    panels = PLANT_PANELS if plant else PANELS
    fig, grid = plt.subplots(
        *((len(panels), 1) if plant else (4, 2)), figsize=(7, 7.5) if plant else (10, 10.5),
        sharex=True, squeeze=False,
    )  # fmt: skip
    axes = grid.ravel()
    for ax, (column, label) in zip(axes, panels, strict=True):
        ax.plot(steps, [float(r[column] or "nan") for r in rows], lw=1.2)
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
        if column.endswith("_rate"):  # a share: from 0
            ax.set_ylim(bottom=0.0)
    total = sum(n for _, n in collisions)
    what = "failure" if plant else "collision"
    if collisions:  # a rug of red ticks along the return panel's foot, one per rollout
        ax = axes[0]
        ax.plot([step for step, _ in collisions], [0.03] * len(collisions), "|", color="red",
                ms=10, transform=ax.get_xaxis_transform(),
                label=f"{what} in training ({total})")  # fmt: skip
    if selected is not None:
        for ax in axes:
            ax.axvline(selected, color=SELECTED_COLOR, ls="--", lw=1.2)
        axes[0].lines[-1].set_label(f"the policy kept, chosen on validation ({selected:,})")
    if collisions or selected is not None:
        axes[0].legend(fontsize=8, loc="lower right")
    title = (title + "; " if title else "") + f"{what}s in training: {total}"
    for ax in grid[-1]:
        ax.set_xlabel("time steps")
        # a few ticks, written short (400k, 1.2M): legible at any run length
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: steps_label(x)))
    fig.suptitle(title)
    fig.tight_layout()
    with replacing(out_png) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _rows(progress_csv: str | Path) -> list[dict[str, float]]:
    """The rollouts of ``progress.csv`` that finished episodes, as numbers."""
    with open(progress_csv, encoding="utf-8") as handle:
        rows = [r for r in csv.DictReader(handle) if r["return"] != ""]
    if not rows:
        raise ValueError(f"{progress_csv} has no finished episodes yet")
    return [{k: float(v) if v != "" else float("nan") for k, v in r.items()} for r in rows]


def _mean(rows: list[dict[str, float]], key: str) -> float:
    return sum(r[key] for r in rows) / len(rows)


def training_story(progress_csv: str | Path) -> list[tuple[str, str]]:
    """What the paper says of its training curves (Section V-B, Fig. 5), each beside what a
    run's ``progress.csv`` shows of the same: ``(the paper, this run)`` pairs. "First" and
    "last" are the means over the first and the last tenth of the rollouts that finished
    episodes."""
    rows = _rows(progress_csv)
    tenth = max(1, len(rows) // 10)
    first, last = rows[:tenth], rows[-tenth:]
    step = [int(r["timesteps"]) for r in rows]

    def change(key: str) -> str:
        return f"{_mean(first, key):,.0f} → {_mean(last, key):,.0f}"

    drops = [k for k in range(1, len(rows)) if rows[k]["return"] < 0.9 * rows[k - 1]["return"]]
    with_safety = [
        k for k in drops
        if rows[k]["activation_episode_rate"] > rows[k - 1]["activation_episode_rate"]
    ]  # fmt: skip
    early = rows[: max(1, len(rows) // 5)]
    peak = max(range(len(early)), key=lambda k: early[k]["speed"])
    lowest = min(range(len(early)), key=lambda k: early[k]["accel_lat"])
    window = min(10, len(rows))
    rolling = [_mean(rows[max(0, k - window + 1) : k + 1], "cut_rate") for k in range(len(rows))]
    below = [k for k, share in enumerate(rolling) if share < 0.2]
    dip = min(range(len(rows)), key=lambda k: rolling[k])
    if not below:
        starts_to_cut = "a rolling mean over 10 rollouts cuts in front in 20 % or more throughout"
    elif below[-1] == len(rows) - 1:
        starts_to_cut = "it does not keep cutting in front in 20 % of the episodes"
    else:
        starts_to_cut = (
            f"the share of episodes that cut in front (a rolling mean over 10 rollouts) is "
            f"lowest at step {step[dip]:,} ({rolling[dip]:.0%}; the first rollouts' cuts are "
            f"the random policy's) and stays at 20 % or more from step {step[below[-1] + 1]:,} on"
        )
    starts_to_cut += f"; {_mean(last, 'cut_rate'):.0%} in the last tenth"
    return [
        (
            "(a) The non-normalised cumulative reward is the main criterion for model "
            "validation; it drops noticeably when the policy explores actions that lead to "
            "Safety controller activation.",
            f"Return per episode {change('return')} (first → last tenth). It fell by more than "
            f"10 % from one rollout to the next {len(drops)} times, {len(with_safety)} of them "
            "with more episodes with a safety action than the rollout before.",
        ),
        (
            "(b) The ADAS term is a penalty for activating the Safety controller, so the "
            "algorithm learns not to involve it.",
            f"ADAS term per episode {change('adas')}; episodes with a safety action "
            f"{_mean(first, 'activation_episode_rate'):.0%} → "
            f"{_mean(last, 'activation_episode_rate'):.0%}.",
        ),
        (
            "(d), (f) In the first 220,000 steps it explores maximising the speed, and the "
            "lateral-acceleration reward drops dramatically.",
            f"In the first fifth of the run the velocity term peaks at step {step[peak]:,} "
            f"({early[peak]['speed']:,.0f}) and the lateral-acceleration term is lowest at step "
            f"{step[lowest]:,} ({early[lowest]['accel_lat']:,.0f}).",
        ),
        (
            "(c), (d), (e), (f) By the end it minimises lane-keeping mistakes, reduces both "
            "accelerations and finds the highest velocity it can.",
            f"Lane keeping {change('lka')}, longitudinal acceleration {change('accel_lon')}, "
            f"lateral acceleration {change('accel_lat')}, velocity {change('speed')} (each "
            "term's sum per episode; higher is better).",
        ),
        ("(not in the paper) Where the policy starts to cut in front.", starts_to_cut + "."),
    ]
