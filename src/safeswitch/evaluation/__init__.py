"""Rollouts, metrics, adversaries and baselines."""
