"""Callbacks of a training run: safety counters, TensorBoard scalars, the progress log and
checkpoints.

TensorBoard scalars (beyond SB3's own ``rollout/`` and ``train/``):

* ``safety/collisions_total`` — collisions since the run started (should stay 0 with a safety
  net);
* ``safety/activation_rate`` — share of the rollout's ticks on which a safety action ran;
* ``safety/activation_episode_rate`` — share of the rollout's finished episodes with one;
* ``outcome/cut_rate``, ``outcome/yield_rate`` — who crossed first, over finished episodes;
* ``reward/return`` and ``reward/<term>`` — per-episode sums of the return and of each Eq. 5
  term, averaged over the rollout's finished episodes (the curves of the paper's Fig. 5).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.io import append_row
from safeswitch.leftturn.rewards import REWARD_TERMS
from safeswitch.progress import Progress

PROGRESS_FIELDS = (
    "timesteps",
    "wall_time_s",
    "episodes",
    "collisions_total",
    "safety_steps_total",
    "activation_rate",
    "activation_episode_rate",
    "cut_rate",
    "yield_rate",
    "return",
    *REWARD_TERMS,
)


class RunMonitor(BaseCallback):
    """What every plant's monitor shares: counters restored on resume, the run's wall time,
    a resumable checkpoint every ``checkpoint_every`` timesteps, and one row per rollout to
    ``progress.csv`` (columns ``fields``) and TensorBoard.

    Args:
        progress_csv: File the per-rollout rows are appended to.
        checkpoint_every: Call ``save_checkpoint`` every this many timesteps.
        save_checkpoint: Writes a resumable checkpoint (given this monitor).
        totals: The counters and their starting values (a checkpoint's on resume).
        fields: The columns of ``progress.csv``.
    """

    def __init__(
        self,
        progress_csv: Path,
        checkpoint_every: int,
        save_checkpoint: Callable[[Any], object],
        totals: dict[str, float],
        fields: tuple[str, ...],
    ) -> None:
        super().__init__()
        self.progress_csv = progress_csv
        self.checkpoint_every = checkpoint_every
        self.save_checkpoint = save_checkpoint
        self.totals = totals
        self.fields = fields
        self._started = time.perf_counter()
        self._wall_before = float(self.totals["wall_time_s"])
        self._next_checkpoint = 0

    @property
    def wall_time_s(self) -> float:
        return self._wall_before + time.perf_counter() - self._started

    def _on_training_start(self) -> None:
        every = self.checkpoint_every
        self._next_checkpoint = (self.num_timesteps // every + 1) * every

    def checkpoint_if_due(self) -> None:
        """A checkpoint once the run has reached the next multiple of ``checkpoint_every``."""
        if self.num_timesteps >= self._next_checkpoint:
            self.totals["wall_time_s"] = self.wall_time_s
            self.save_checkpoint(self)
            self._next_checkpoint += self.checkpoint_every

    def write_row(self, row: dict[str, float], tags: dict[str, str]) -> None:
        """``row`` to TensorBoard (each key of ``tags`` the row has, under its tag) and
        appended to ``progress.csv`` (a header first in a new file; a column the row lacks
        left empty)."""
        for key, tag in tags.items():
            if key in row:
                self.logger.record(tag, row[key])
        append_row(self.progress_csv, self.fields, row)


#: TensorBoard tags of the left turn's progress columns.
TAGS = {
    "collisions_total": "safety/collisions_total",
    "activation_rate": "safety/activation_rate",
    "activation_episode_rate": "safety/activation_episode_rate",
    "cut_rate": "outcome/cut_rate",
    "yield_rate": "outcome/yield_rate",
    "return": "reward/return",
    **{name: f"reward/{name}" for name in REWARD_TERMS},
}


class TrainingMonitor(RunMonitor):
    """Counts what matters for safe training on the left turn and logs it once per rollout
    (the arguments are :class:`RunMonitor`'s; ``totals``: a checkpoint's counters)."""

    def __init__(
        self,
        progress_csv: Path,
        checkpoint_every: int,
        save_checkpoint: Callable[[TrainingMonitor], object],
        totals: dict[str, float] | None = None,
    ) -> None:
        counters: dict[str, float] = {
            "collisions": 0,
            "collision_episodes": 0,
            "lost_control": 0,
            "failures": 0,
            "safety_steps": 0,
            "safety_episodes": 0,
            "episodes": 0,
            "ticks": 0,
            "wall_time_s": 0.0,
        } | (totals or {})
        super().__init__(progress_csv, checkpoint_every, save_checkpoint, counters, PROGRESS_FIELDS)
        self._reset_rollout()

    def _reset_rollout(self) -> None:
        self._ticks = 0
        self._safety_ticks = 0
        self._episodes: list[dict[str, Any]] = []

    def _on_step(self) -> bool:
        infos = self.locals["infos"]
        record = infos.record
        n = record.collision.shape[0]
        self._ticks += n
        self._safety_ticks += int(record.safety_active.sum())
        self.totals["ticks"] += n
        self.totals["collisions"] += int(record.collision.sum())
        self.totals["lost_control"] += int(record.lost_control.sum())
        self.totals["safety_steps"] += int(record.safety_active.sum())
        for i in np.flatnonzero(self.locals["dones"]):
            episode = infos[int(i)]["episode"]
            self._episodes.append(episode)
            self.totals["episodes"] += 1
            self.totals["collision_episodes"] += int(episode["collision"])
            self.totals["failures"] += int(episode["collision"] or episode["lost_control"])
            self.totals["safety_episodes"] += int(episode["safety_steps"] > 0)
        self.checkpoint_if_due()
        return True

    def _on_rollout_end(self) -> None:
        row: dict[str, float] = {
            "timesteps": self.num_timesteps,
            "wall_time_s": round(self.wall_time_s, 3),
            "episodes": self.totals["episodes"],
            "collisions_total": self.totals["collisions"],
            "safety_steps_total": self.totals["safety_steps"],
            "activation_rate": self._safety_ticks / max(self._ticks, 1),
        }
        episodes = self._episodes
        if episodes:
            row["activation_episode_rate"] = float(
                np.mean([e["safety_steps"] > 0 for e in episodes])
            )
            row["cut_rate"] = float(np.mean([e["outcome"] == 1 for e in episodes]))
            row["yield_rate"] = float(np.mean([e["outcome"] == 2 for e in episodes]))
            row["return"] = float(np.mean([e["r"] for e in episodes]))
            for name in REWARD_TERMS:
                row[name] = float(np.mean([e[f"term_{name}"] for e in episodes]))
        self.write_row(row, TAGS)
        self._reset_rollout()


class ProgressLines(BaseCallback):
    """Training progress as plain lines (steps done, rate, ETA) every ``every`` seconds, for
    logs and terminals without a progress bar."""

    def __init__(self, total: int, label: str, every: float = 15.0) -> None:
        super().__init__()
        self.progress = Progress(total, label, unit="steps", every=every)

    def _on_step(self) -> bool:
        self.progress.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.progress.close()
