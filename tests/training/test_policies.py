"""Loading and running trained policies."""

from __future__ import annotations

import numpy as np
import pytest

from safeswitch.leftturn.make import build_task
from safeswitch.training.policies import SHIPPED, load_policy


@pytest.mark.parametrize(
    "name", sorted(f for f in set(SHIPPED.values()) if not f.startswith("highway_"))
)  # the highway-env policies: tests/evaluation/test_shipped_highway.py
def test_the_fast_deterministic_path_acts_as_sb3_predict(name):
    policy = load_policy(name.replace("_", "-"))
    assert policy._actor is not None  # the shipped policies take the fast path
    # each policy's own observation: the traffic policies observe their traffic, `certified`
    # its go predictor's probability too
    task = build_task(None, policy.config.env, traffic=policy.config.traffic_settings)
    rng = np.random.default_rng(0)
    # observations from real scenes, and far outside them (the clip to [-1, 1] matters there)
    obs = task.observe(task.initial(task.draw_scenarios(0, np.arange(2048), np.zeros(2048, int))))
    wild = rng.normal(0.0, 50.0, size=(2048, obs.shape[1])).astype(np.float32)
    for batch in (obs, wild):
        fast = policy.act(batch)
        reference, _ = policy.model.predict(policy.normalise(batch), deterministic=True)
        np.testing.assert_allclose(fast, reference.reshape(-1), rtol=0, atol=2e-6)
        assert np.all(np.abs(fast) <= 1.0)
    assert np.any(np.abs(policy.act(wild)) == 1.0)
