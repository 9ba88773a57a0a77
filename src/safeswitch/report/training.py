"""Training curves like the paper's Fig. 5, from a run's ``progress.csv``."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

PANELS = (
    ("return", "(a) cumulative reward (per episode)"),
    ("adas", "(b) ADAS"),
    ("lka", "(c) lane keeping"),
    ("speed", "(d) velocity"),
    ("accel_lon", "(e) longitudinal acceleration"),
    ("accel_lat", "(f) lateral acceleration"),
)


def training_curves(progress_csv: str | Path, out_png: str | Path, title: str = "") -> None:
    """Six panels: the episode return and each reward term's per-episode sum against
    timesteps (not normalised)."""
    with open(progress_csv, encoding="utf-8") as handle:
        rows = [r for r in csv.DictReader(handle) if r["return"] != ""]
    if not rows:
        raise ValueError(f"{progress_csv} has no finished episodes yet")
    steps = [int(r["timesteps"]) for r in rows]
    fig, axes = plt.subplots(3, 2, figsize=(10, 8), sharex=True)
    for ax, (key, label) in zip(axes.ravel(), PANELS, strict=True):
        ax.plot(steps, [float(r[key]) for r in rows], lw=1.2)
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time steps")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    tmp = Path(out_png).with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(out_png)
