import os

import pytest

from safeswitch.training import train
from safeswitch.training.callbacks import TrainingMonitor
from safeswitch.training.generic import EnvMonitor


@pytest.fixture(scope="session", autouse=True)
def _sb3_logs_in_the_session_tmp(tmp_path_factory):
    """An SB3 model learning without a logger of its own (a test's bare ``PPO(...).learn``)
    makes a folder ``/tmp/SB3-<time>`` per call; they go to the session's temporary folder
    instead (``SB3_LOGDIR``, which SB3 reads; inherited by the commands tests start)."""
    previous = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))
    yield
    if previous is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = previous


@pytest.fixture
def interrupted_training(monkeypatch):
    """``run(config, out, at)``: train until ``at`` timesteps, then Ctrl-C (the interrupt is
    raised after a rollout's bookkeeping, as a user's would land); resuming is left to the test."""

    def run(config, out, at):
        monitors = (TrainingMonitor, EnvMonitor)  # the left turn's and any plant's
        originals = [m._on_rollout_end for m in monitors]

        def interrupting(original):
            def interrupt(self):
                original(self)
                if self.num_timesteps >= at:
                    raise KeyboardInterrupt

            return interrupt

        for monitor, original in zip(monitors, originals, strict=True):
            monkeypatch.setattr(monitor, "_on_rollout_end", interrupting(original))
        with pytest.raises(KeyboardInterrupt):
            train(config, out, progress_bar=False)
        for monitor, original in zip(monitors, originals, strict=True):
            monkeypatch.setattr(monitor, "_on_rollout_end", original)

    return run


@pytest.fixture
def benchmark_module(monkeypatch):
    """``benchmark_module("plants")``: a script of ``benchmarks/`` imported as a module of its
    own (``benchmarks/`` on the path for its ``_common``), forgotten after the test."""
    import importlib.util
    import sys
    from pathlib import Path

    benchmarks = Path(__file__).resolve().parent.parent / "benchmarks"
    monkeypatch.syspath_prepend(str(benchmarks))
    loaded = []

    def load(name):
        spec = importlib.util.spec_from_file_location(
            f"{name}_under_test", benchmarks / f"{name}.py"
        )
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        loaded.append(spec.name)
        return module

    yield load
    for name in loaded:
        sys.modules.pop(name, None)
