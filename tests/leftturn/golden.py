"""Per-tick decisions of the left-turn task on the README's scenarios, digested per episode.

``python -m tests.leftturn.golden`` writes ``tests/data/leftturn_golden.npz``; ``test_golden.py``
replays the same runs on the current code and requires every digest to be equal bit for bit: a
refactoring must not change a single decision.

Two records: ``leftturn_golden_pre_friction.npz`` was written by commit 01d647c (before the task
ran its switching through ``safeswitch.core``) and gated every change up to the friction circle
(issue #37); ``leftturn_golden.npz`` was written after it. The older record still gates the
one-kernel logics: with the curve certificate switched off, every decision is what 01d647c
made, except in the episodes where the ego's tyres slid (``test_golden.py``).

The learned runs drive their policies through ``portable.py`` (numpy, no BLAS), not torch:
torch's products differ in their last bits between CPUs, and a record must hold on every
machine. Both records' learned runs were written that way on 2026-12-03 (the pre-friction one
by ``record_pre_friction.py`` on a checkout of 08b80e9, whose decisions are 01d647c's); the
other runs are as first recorded.

Each run is a controller and a switching logic on 300 random scenarios (seed 1000003, the
README's evaluation seed). Per episode and tick the executed throttle and brake, the safety
flag, the reason code, the reward and the ego's speed are folded into one float64 digest per
column (a sum weighted by the tick index, so a change on any tick changes it).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from safeswitch.evaluation.adversaries import bang_bang, constant, uniform
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.policies import TrainedPolicy, load_policy
from tests.leftturn.portable import portable_driver

PATH = Path(__file__).resolve().parent.parent / "data" / "leftturn_golden.npz"
PRE_FRICTION = PATH.with_name("leftturn_golden_pre_friction.npz")
#: The learned policies the runs drive (``golden_policies/<name>``: the shipped policies' files
#: at commit f53b12d, before their retraining).
POLICIES = PATH.with_name("golden_policies")
EPISODES = 300
SEED = 1_000_003
COLUMNS = ("throttle", "brake", "safety_active", "reason", "reward", "ego_speed", "separation")


def runs():
    """(name, task config, policy factory) of every recorded run."""
    # the policies shipped as `paper-warm` (`paper` when the runs were recorded) and
    # `paper-scratch` until they were retrained on the plant with tyre friction (issue #39),
    # kept as test data: the golden runs pin the task's decisions, whatever ships
    shipped = load_policy(POLICIES / "paper_warm")
    scratch = load_policy(POLICIES / "paper_scratch")
    episode = {"episode": {"learned_scope": "episode"}}

    def learned(policy):
        # computed the same on every CPU (portable.py), not through torch's MKL products:
        # the golden runs pin the task's decisions, not the inference path
        act = portable_driver(portable_parameters(policy))
        return lambda: act

    return [
        ("rule_paper", resolve_config({"episode": {"learned_scope": "never"}}),
         lambda: constant(0.0)),
        ("shipped_paper", resolve_config(episode), learned(shipped)),
        ("shipped_certified", resolve_config(episode, switching="certified"), learned(shipped)),
        ("scratch_window_paper", resolve_config(None), learned(scratch)),
        ("uniform_paper", resolve_config(episode), lambda: uniform(np.random.default_rng(1))),
        ("uniform_certified", resolve_config(episode, switching="certified"),
         lambda: uniform(np.random.default_rng(2))),
        ("bang_bang_none", resolve_config(episode, switching="none"),
         lambda: bang_bang(np.random.default_rng(3))),
    ]  # fmt: skip


def portable_parameters(policy: TrainedPolicy) -> dict[str, np.ndarray]:
    """The actor of ``policy`` (a plain tanh MLP, as the golden policies are) and its
    observation statistics as float64 arrays: ``w0, b0, w1, b1, …``, ``mean``, ``var``,
    ``clip``, ``epsilon``, ``low``, ``high`` (what ``portable.portable_driver`` reads)."""
    net = policy.model.policy
    modules = [*net.mlp_extractor.policy_net, net.action_net]
    linear = [m for m in modules if isinstance(m, torch.nn.Linear)]
    assert all(isinstance(m, (torch.nn.Linear, torch.nn.Tanh)) for m in modules), modules
    assert len(modules) == 2 * len(linear) - 1, "a tanh after every hidden layer"
    norm = policy.normalizer
    assert norm is not None and norm.norm_obs, "the golden policies normalise observations"
    out = {
        "mean": np.asarray(norm.obs_rms.mean, dtype=np.float64),
        "var": np.asarray(norm.obs_rms.var, dtype=np.float64),
        "clip": np.float64(norm.clip_obs),
        "epsilon": np.float64(norm.epsilon),
        "low": np.float64(net.action_space.low[0]),
        "high": np.float64(net.action_space.high[0]),
    }
    for i, layer in enumerate(linear):
        out[f"w{i}"] = layer.weight.detach().numpy().astype(np.float64)
        out[f"b{i}"] = layer.bias.detach().numpy().astype(np.float64)
    return out


def digest(config, make_policy, task=None) -> np.ndarray:
    """``[EPISODES, len(COLUMNS)]`` tick-weighted sums of the recorded columns (episodes are
    not reset: every episode runs the whole horizon, as a rollout's batch does)."""
    return digest_and_slides(config, make_policy, task)[0]


def digest_and_slides(config, make_policy, task=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`digest`, and per episode whether the ego's tyres slid on some tick."""
    task = task or LeftTurnTask(config)
    n = EPISODES
    state = task.initial(task.draw_scenarios(SEED, np.arange(n), np.zeros(n, dtype=np.int64)))
    policy = make_policy()
    out = np.zeros((n, len(COLUMNS)))
    slid = np.zeros(n, dtype=bool)
    observation = task.observe(state)
    rule = task.reasons.index("rule_in_charge") if "rule_in_charge" in task.reasons else -1
    for tick in range(config.episode.horizon_ticks):
        state, record = task.step(state, policy(observation, state, tick))
        observation = record.observation
        slid |= record.grip_demand > 1.0
        for j, name in enumerate(COLUMNS):
            value = np.asarray(getattr(record, name), dtype=np.float64)
            if name == "reason":  # 01d647c said "learned" where the rule's proposal ran
                value = np.where(value == rule, 0.0, value)
            out[:, j] += (tick + 1) * value
    return out, slid


def main() -> int:
    data = {name: digest(config, make) for name, config, make in runs()}
    PATH.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(PATH, **data)
    print(f"wrote {PATH} ({', '.join(data)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
