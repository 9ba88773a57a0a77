"""Per-tick decisions of the left-turn task on the README's scenarios, digested per episode.

``python tests/leftturn/golden.py`` writes ``tests/data/leftturn_golden.npz``; ``test_golden.py``
replays the same runs on the current code and requires every digest to be equal bit for bit: a
refactoring must not change a single decision.

Two records: ``leftturn_golden_pre_friction.npz`` was written by commit 01d647c (before the task
ran its switching through ``safeswitch.core``) and gated every change up to the friction circle
(issue #37); ``leftturn_golden.npz`` was written after it. The older record still gates the
one-kernel logics: with the curve certificate switched off, every decision is what 01d647c
made, except in the episodes where the ego's tyres slid (``test_golden.py``).

Each run is a controller and a switching logic on 300 random scenarios (seed 1000003, the
README's evaluation seed). Per episode and tick the executed throttle and brake, the safety
flag, the reason code, the reward and the ego's speed are folded into one float64 digest per
column (a sum weighted by the tick index, so a change on any tick changes it).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from safeswitch.evaluation.adversaries import bang_bang, constant, uniform
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.policies import load_policy

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
        # SB3's own predict, as when the runs were recorded: the golden runs pin the task's
        # decisions, not the inference path (TrainedPolicy.act computes the same actions up to
        # the last bit of a float32 tanh; tests/training/test_policies.py checks that).
        def act(obs, state, tick):
            actions, _ = policy.model.predict(policy.normalise(obs), deterministic=True)
            return np.asarray(actions, dtype=np.float64).reshape(obs.shape[0])

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
