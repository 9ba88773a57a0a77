"""How well does the go predictor judge the states the policy itself drives through? (issue
#39; docs/learning_experiments.md, "The exploration noise annealed further in traffic").

The `traffic-certified` policy's go predictor was fitted on the states of random drivers and of
rule drivers that go on a first fit's verdict (experiments/go_predictor.py), not on the states
the policy drives through. A DAgger round on the policy's own states would help only if the
predictor is worse there. This one-off probe drives the policy under `certified` on `train`
scenes of an unseen seed (3000003; the family the predictor was sampled in) and on the `test`
scenes of seed 1000003, and at each of its decisions before the first conflict zone compares
the predictor's probability (the observation's last value) with the simulated go check it was
fitted to (the gap planner's :meth:`~safeswitch.evaluation.traffic_planner.GapPlanner.passes`),
overall and by the ego's speed. No training; the policy is unchanged.

Run: ``python experiments/probe_go_on_policy.py [MODEL [EPISODES]]`` (default the shipped
`traffic-certified`, 300 scenes per family; one core, about 20 s per family).
"""

import sys
import time
from dataclasses import replace

import numpy as np

from safeswitch.app.evaluate import controller_setup, fit_observations
from safeswitch.evaluation.evaluate import scenario_chunks
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.leftturn.config import observed_as, traffic_config
from safeswitch.leftturn.make import build_task
from safeswitch.training.config import load_config

#: Speed bands of the breakdown [m/s].
BANDS = ((0.0, 1.0), (1.0, 4.0), (4.0, 7.0), (7.0, 9.0))


def scores(p: np.ndarray, y: np.ndarray) -> str:
    """The predictor's Brier score and its mistakes at 0.5 on decisions ``p`` (labels ``y``)."""
    return (
        f"go share {y.mean():.3f}, Brier {((p - y) ** 2).mean():.4f}, right at 0.5 "
        f"{((p > 0.5) == y).mean():.2%}, false go {((p > 0.5) & ~y).sum()}, missed go "
        f"{((p < 0.5) & y).sum()}"
    )


def decisions(model: str, family: str, seed: int, episodes: int) -> tuple[np.ndarray, ...]:
    """The predictor's probability, the simulated check's verdict and the ego's speed at each of
    ``model``'s decisions before the first conflict zone, on ``episodes`` scenes of ``family``
    (seed ``seed``) under `certified`."""
    config = load_config("traffic_certified")
    env = replace(config.env, switching="certified")
    task = build_task(
        None, env, traffic=observed_as(traffic_config(family), traffic_config(config.traffic))
    )
    ((_, scenes),) = scenario_chunks(task, "random", episodes, seed)
    _, policy = controller_setup("learned", model, "certified")
    policy = fit_observations(policy, model, task)
    planner = GapPlanner(task)
    interval = task.config.episode.decision_interval
    live = np.ones(episodes, dtype=bool)
    probability: list[np.ndarray] = []
    label: list[np.ndarray] = []
    speed: list[np.ndarray] = []

    def drive(obs, state, tick):
        if tick % interval == 0:
            rows = np.flatnonzero(live & (state.world.progress[:, 0] <= planner.first_entry))
            if rows.size:
                probability.append(obs[rows, -1].copy())
                label.append(planner.passes(state.take(rows)))
                speed.append(state.world.vehicles.speed[rows, 0].copy())
        return policy(obs, state, tick)

    def on_tick(state, record, tick):
        live[:] &= ~(record.terminated | record.truncated)

    rollout(task, scenes, drive, on_tick)
    return np.concatenate(probability), np.concatenate(label), np.concatenate(speed)


def main() -> None:
    model = sys.argv[1] if len(sys.argv) > 1 else "traffic-certified"
    episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 300
    for family, seed in (("train", 3_000_003), ("test", 1_000_003)):
        start = time.time()
        p, y, v = decisions(model, family, seed, episodes)
        print(f"{family}: {len(p)} decisions, {scores(p, y)} ({time.time() - start:.0f} s)")
        for low, high in BANDS:
            band = (v >= low) & (v < high)
            if band.any():
                print(f"  ego at {low:.0f}-{high:.0f} m/s: {band.sum()} decisions, "
                      f"{scores(p[band], y[band])}")  # fmt: skip


if __name__ == "__main__":
    main()
