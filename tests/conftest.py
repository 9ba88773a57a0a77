import pytest

from safeswitch.training import train
from safeswitch.training.callbacks import TrainingMonitor


@pytest.fixture
def interrupted_training(monkeypatch):
    """``run(config, out, at)``: train until ``at`` timesteps, then Ctrl-C (the interrupt is
    raised after a rollout's bookkeeping, as a user's would land); resuming is left to the test."""

    def run(config, out, at):
        original = TrainingMonitor._on_rollout_end

        def interrupt(self):
            original(self)
            if self.num_timesteps >= at:
                raise KeyboardInterrupt

        monkeypatch.setattr(TrainingMonitor, "_on_rollout_end", interrupt)
        with pytest.raises(KeyboardInterrupt):
            train(config, out, progress_bar=False)
        monkeypatch.setattr(TrainingMonitor, "_on_rollout_end", original)

    return run
