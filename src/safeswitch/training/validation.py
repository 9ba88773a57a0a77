"""Model selection on a validation set: which policy of a run is the run's policy.

Every ``validation.every`` timesteps the deterministic policy (the Gaussian's mean, as it is
evaluated and deployed) drives the validation scenarios — random scenarios drawn with their own
seed, never trained on and never in the final evaluation, under the logic it trains with or
``validation.switching`` — and its mean return there is its score (the paper's criterion for
learned model validation; ``validation.criterion`` can put the fewest collisions first). The
best policy so far is saved whole into ``best/`` of the run directory (model and observation
statistics, written into a temporary folder and renamed); each validation is a row of
``validation.csv`` with the evaluation's summary fields. At the end of the run the best policy
becomes the run's ``model.zip`` and the last one is kept in ``last/``.

The oracle's plan of the validation scenarios is made once (the other vehicles never react to
the ego's policy in the paper's scene; in traffic the oracle plans against the others' world
without the ego), so a validation costs one batched rollout.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
from safeswitch.evaluation.oracle import OraclePlan
from safeswitch.leftturn.task import build_task
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import TrainedPolicy

#: Columns of ``validation.csv``: when, the score, then the evaluation's summary fields.
VALIDATION_FIELDS = (
    "timesteps",
    "mean_return",
    "collisions",
    "safety_activation_episodes",
    "comfort_violation_fraction",
    "stops",
    "cut_episodes",
    "cleared_episodes",
    "mean_efficiency",
    "best",
)


class Validator(BaseCallback):
    """Validates the policy after the rollouts that reach each ``every`` timesteps and keeps
    the best (see the module docstring).

    Args:
        config: The run's configuration (its ``validation`` section set).
        run: The run directory (a resumed run's ``best/`` is the best so far).
    """

    def __init__(self, config: TrainConfig, run: Path) -> None:
        super().__init__()
        v = config.validation
        self.config, self.run = config, run
        logic = {} if v.switching is None else {"switching": v.switching}
        self.task = build_task(None, config.env, traffic=config.traffic_settings, **logic)
        ids = np.arange(v.episodes)
        self.scenarios = self.task.draw_scenarios(v.seed, ids, np.zeros(v.episodes, dtype=int))
        self._plan: OraclePlan | None = None
        saved = run / "best" / "state.json"
        #: The best score and when it was reached (``None``: no validation yet).
        self.state: dict[str, Any] = (
            json.loads(saved.read_text(encoding="utf-8"))
            if saved.is_file()
            else {"best_return": None, "best_timesteps": None}
        )
        self._next = 0

    def _on_training_start(self) -> None:
        v = self.config.validation
        self._next = max((self.num_timesteps // v.every + 1) * v.every, v.start)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps < self._next:
            return
        every = self.config.validation.every
        self._next = (self.num_timesteps // every + 1) * every
        summary = self.validate()
        score = float(summary["mean_return"])
        collisions = int(summary["collisions"])
        better = self.state["best_return"] is None or self._key(collisions, score) > self._key(
            self.state.get("best_collisions", 0), self.state["best_return"]
        )
        if better:
            self.state = {
                "best_return": score,
                "best_collisions": collisions,
                "best_timesteps": int(self.num_timesteps),
            }
            self._save_best()
        row = {"timesteps": self.num_timesteps, **summary, "best": int(better)}
        path = self.run / "validation.csv"
        new_file = not path.exists()
        with open(path, "a", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=VALIDATION_FIELDS, extrasaction="ignore")
            if new_file:
                writer.writeheader()
            writer.writerow(row)
        self.logger.record("validation/return", score)
        self.logger.record("validation/efficiency", summary.get("mean_efficiency", np.nan))
        self.logger.record("validation/safety_activation_episodes",
                           summary["safety_activation_episodes"])  # fmt: skip

    def _key(self, collisions: int, mean_return: float) -> tuple[float, float]:
        """What ``validation.criterion`` maximises."""
        if self.config.validation.criterion == "collisions_then_return":
            return (-collisions, mean_return)
        return (0.0, mean_return)

    def validate(self) -> dict[str, Any]:
        """The current deterministic policy's summary on the validation scenarios."""
        env = self.model.get_env()
        normalizer = env if self.config.ppo.normalize_observations else None
        policy = TrainedPolicy(self.model, normalizer, self.config, self.run)  # type: ignore[arg-type]
        result, self._plan = run_controller(
            self.task, policy.as_policy(), self.scenarios, plan=self._plan, trace=False
        )
        return summary_against_oracle(result, self._plan, self.task.config.episode.horizon_s)

    def _save_best(self) -> None:
        tmp, final = self.run / ".best.tmp", self.run / "best"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        self.model.save(tmp / "model.zip")
        self.model.get_env().save(str(tmp / "vecnormalize.pkl"))  # type: ignore[union-attr]
        (tmp / "state.json").write_text(json.dumps(self.state), encoding="utf-8")
        shutil.rmtree(final, ignore_errors=True)
        os.replace(tmp, final)


def select_best(run: Path) -> None:
    """Make the validated best policy of ``run`` the run's policy: the last one moves to
    ``last/``, ``best/``'s model and statistics take its place (each file renamed whole)."""
    last = run / "last"
    last.mkdir(exist_ok=True)
    for name in ("model.zip", "vecnormalize.pkl"):
        os.replace(run / name, last / name)
        shutil.copyfile(run / "best" / name, run / f".{name}.tmp")
        os.replace(run / f".{name}.tmp", run / name)
