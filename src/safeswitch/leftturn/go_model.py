"""A learned go predictor in the left turn's observation (ours; see :class:`GoModel`)."""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import ThreadpoolController

from safeswitch.core.config import ConfigError

#: The logit is clipped to ``±GO_LOGIT_BOUND`` before the sigmoid (no overflow in ``exp``).
GO_LOGIT_BOUND = 30.0


@cache
def _blas() -> ThreadpoolController:
    """The process's numeric thread pools (found once)."""
    return ThreadpoolController()


class GoModel:
    """A learned go predictor (``episode.go_model`` in the single-car scene,
    ``traffic.go_model`` in traffic; ours): a small tanh MLP on the standardised observation
    whose output is the probability that the planners' fast drive from the current state gets
    past every conflict zone without the certified filter acting — the gap planner's go check
    (:meth:`~safeswitch.evaluation.traffic_planner.GapPlanner.goes`), learned from simulated
    outcomes by ``experiments/go_predictor.py`` (traffic) or ``experiments/go_leftturn.py``
    (the single-car scene), which write the ``.npz`` read here (``mean``, ``std``, then ``w0``,
    ``b0``, ``w1``, ``b1``, ... with ``x @ w + b``, tanh between the layers, one logit out).

    Args:
        path: The ``.npz``.
        width: The width of the observation it reads (checked against the file).
        setting: The configuration key that names it (for the messages).

    Raises:
        ConfigError: The file is not such a model, or reads another width.
    """

    def __init__(self, path: str, width: int, setting: str) -> None:
        try:
            with np.load(path) as data:
                arrays = {k: np.asarray(data[k], dtype=np.float32) for k in data.files}
        except (OSError, ValueError) as error:
            raise ConfigError(f"{setting}={path!r} cannot be read: {error}") from error
        layers = sum(1 for k in arrays if k.startswith("w"))
        names = {"mean", "std", *(f"{p}{i}" for i in range(layers) for p in "wb")}
        if layers == 0 or set(arrays) != names:
            raise ConfigError(
                f"{setting}={path!r} holds {sorted(arrays)}, not a go model's mean, "
                f"std, w0, b0, ... (experiments/go_predictor.py and go_leftturn.py write one)"
            )
        if arrays["mean"].shape != (width,) or arrays["w0"].shape[0] != width:
            raise ConfigError(
                f"{setting}={path!r} reads observations of width "
                f"{arrays['mean'].shape[0]}, this task's have {width} (a model learned with "
                f"other observation settings: traffic.observe / observed, "
                f"episode.observe_time_left)"
            )
        self.setting = setting
        self.mean, self.scale = arrays["mean"], 1.0 / arrays["std"]
        self.layers = [(arrays[f"w{i}"], arrays[f"b{i}"]) for i in range(layers)]

    def __call__(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The probability per row of ``observation`` ``[B, width]``, ``[B]`` float32.

        Computed with one BLAS thread whatever the process allows: OpenBLAS splits a product
        differently on two threads and rounds differently, and the probability is a policy
        input, so a run would otherwise depend on ``OPENBLAS_NUM_THREADS`` (measured: the
        `certified` recipe's first rollout already differed)."""
        h = (observation - self.mean) * self.scale
        with _blas().limit(limits=1, user_api="blas"):
            for i, (w, b) in enumerate(self.layers):
                h = h @ w + b
                if i < len(self.layers) - 1:
                    h = np.tanh(h)
        logit = np.clip(h[:, 0], -GO_LOGIT_BOUND, GO_LOGIT_BOUND)
        return (1.0 / (1.0 + np.exp(-logit))).astype(np.float32)
