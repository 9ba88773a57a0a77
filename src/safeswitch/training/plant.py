"""What the one training pipeline (:mod:`safeswitch.training.pipeline`) needs of a plant."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from safeswitch.training.ppo import SwitchPPO
from safeswitch.training.validation import BestPolicy


class Plant:
    """What the pipeline needs of a plant (the left turn: ``run.LeftTurnPlant``; any
    Gymnasium plant: ``generic.GymPlant``).

    Attributes:
        config: The run's configuration.
    """

    config: Any

    def dump(self) -> str:
        """The configuration as the run's ``config.yaml``."""
        raise NotImplementedError

    def vec_env(self) -> VecEnv:
        """The training environments (the switch inside)."""
        raise NotImplementedError

    def check(self, vec: VecEnv) -> None:
        """Refuse, before anything is written, what the plant cannot serve."""

    def learning(self, vec: VecEnv) -> Any:
        """The learning-only wrappers around ``vec``: ``env`` (what ``VecNormalize`` wraps),
        ``schedules(run)`` (their callbacks), ``state()`` / ``restore(checkpoint)``."""
        raise NotImplementedError

    def monitor(
        self, run: Path, save: Callable[[Any], object], totals: dict[str, float] | None
    ) -> Any:
        """The progress monitor (a callback with ``totals`` and ``wall_time_s``)."""
        raise NotImplementedError

    def vec_state(self, vec: VecEnv) -> dict[str, Any]:
        """What a checkpoint keeps of the environments."""
        return {}

    def restore_vec(self, vec: VecEnv, checkpoint: dict[str, Any]) -> None:
        """The environments as a checkpoint left them."""

    def warm_start(self, model: SwitchPPO, env: VecNormalize, run: Path) -> bool:
        """A warm start before PPO, if configured (its record written into ``run``)."""
        return False

    def validator(self, run: Path) -> BestPolicy | None:
        """The validator (``None`` without ``validation.every``)."""
        return None

    def refine(self, run: Path, train: Callable[..., dict[str, Any]]) -> dict[str, Any] | None:
        """A stage after PPO that may replace the run's policy (the left turn's search-guided
        refinement); returns its record for ``metrics.json`` (``None``: none here). ``train``
        is the pipeline's own, for a stage that trains a phase of its own."""
        return None

    def evaluate(self, run: Path) -> dict[str, Any]:
        """The run's policy on the final evaluation set."""
        raise NotImplementedError

    def header(self, run: Path) -> dict[str, Any]:
        """The plant's fields at the top of ``metrics.json``."""
        return {}

    def training(self, totals: dict[str, float]) -> dict[str, Any]:
        """``metrics.json``'s ``training`` section from the monitor's totals."""
        raise NotImplementedError
