"""Stable-Baselines3 glue: the training configuration, callbacks, checkpoints and runs."""
