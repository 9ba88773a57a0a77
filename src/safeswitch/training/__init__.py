"""Stable-Baselines3 glue: the training configuration, callbacks, checkpoints, and the one
training pipeline every plant trains through (:func:`train`, imported on first use: it brings
in torch)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["train"]

if TYPE_CHECKING:
    from safeswitch.training.pipeline import train


def __getattr__(name: str) -> Any:
    if name == "train":
        from safeswitch.training.pipeline import train

        return train
    raise AttributeError(f"module 'safeswitch.training' has no attribute {name!r}")
