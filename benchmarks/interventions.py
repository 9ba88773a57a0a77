"""Learning from the interventions against the penalty alone, on a plant through the generic
pipeline (issue #39, item 4).

Trains ``--env`` under ``--switching`` with each ``--seeds`` value twice — the penalty alone
(``policy.intervention_imitation: 0``) and the penalty plus the fit toward the executed safety
action (``--weight``) — one torch thread, two runs at a time, and evaluates each run's policy
under the same logic on ``--episodes`` episodes of the evaluation seed: failures (as the plant
declares them), the share of steps the Safety controller acted on, the mean return; and from
training, failures and safety steps. Every run's row is reported.

The default plant is the test suite's cart before a wall (``tests/core/user_plant.py``: its
failure is ``info["hit_wall"]``, its logic ``stopping-distance``), imported as a user's plant
would be (``module:EnvId``).

Run: ``python benchmarks/interventions.py [--env ID] [--switching LOGIC] [--penalty P]
[--timesteps N] [--seeds 1 2 3] [--weight W] [--set KEY=VALUE ...] [--out FILE]``; writes
``benchmarks/results/interventions_<plant>.json``. ``--set`` changes a setting of every run's
configuration as ``safeswitch train --set`` does (e.g. ``ppo.learning_rate=5e-4``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import _common

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results"
sys.path.insert(0, str(ROOT))  # the default plant lives in the test suite

WALL = "tests.core.user_plant:UserWall-v0"


def one_run(env_id: str, switching: str, penalty: float, timesteps: int, seed: int,
            weight: float, episodes: int, settings: tuple[str, ...] = ()
            ) -> dict[str, object]:  # fmt: skip
    from safeswitch.core.config import with_settings
    from safeswitch.training import train
    from safeswitch.training.config import EnvPolicyConfig, EnvTrainConfig

    config = EnvTrainConfig(
        env_id=env_id, switching=switching, penalty=penalty, timesteps=timesteps, seed=seed,
        n_envs=4, torch_threads=1, eval_episodes=episodes,
        policy=EnvPolicyConfig(intervention_imitation=weight),
    )  # fmt: skip
    config = with_settings(config, settings)
    with tempfile.TemporaryDirectory() as run:
        metrics = train(config, run, progress_bar=False)
    t, e = metrics["training"], metrics["evaluation"]
    return {
        "seed": seed, "intervention_imitation": weight, "timesteps": metrics["timesteps"],
        "wall_time_s": metrics["wall_time_s"], "training_failures": t["failures"],
        "training_safety_steps": t["safety_activation_steps"], "training_steps": t["steps"],
        "failures": e["failures"], "safety_share": e["safety_share"],
        "safety_activation_episodes": e["safety_activation_episodes"],
        "mean_return": e["mean_return"], "episodes": e["episodes"],
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default=WALL)
    parser.add_argument("--switching", default="stopping-distance")
    parser.add_argument("--penalty", type=float, default=-1.0)
    parser.add_argument("--timesteps", type=int, default=40_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--weight", type=float, default=1.0)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="change a setting of every run (repeatable)",
    )
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    from safeswitch.core.config import ConfigError, with_settings
    from safeswitch.training.config import EnvTrainConfig

    try:  # a bad setting is refused before any run starts, by name
        with_settings(EnvTrainConfig(env_id=args.env), args.set)
    except ConfigError as exc:
        parser.error(str(exc))
    jobs = [(s, w) for s in args.seeds for w in (0.0, args.weight)]
    settings = tuple(args.set)
    with _common.pool(2) as pool:
        common = (args.env, args.switching, args.penalty, args.timesteps)
        futures = [pool.submit(one_run, *common, s, w, args.episodes, settings) for s, w in jobs]
        rows = [f.result() for f in futures]
    plant = args.env.rpartition(":")[2].split("/")[-1]
    out = args.out or RESULTS / f"interventions_{plant}.json"
    result = {
        "benchmark": "interventions", **_common.machine(), "env_id": args.env,
        "switching": args.switching, "penalty": args.penalty, "weight": args.weight,
        "settings": list(settings), "runs": rows,
    }  # fmt: skip
    _common.publish(result, out, False)
    print(f"{args.env} under {args.switching}, penalty {args.penalty}, {args.timesteps:,} steps")
    print("| seed | imitation | training failures | failures | safety share | return |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['seed']} | {r['intervention_imitation']} | {r['training_failures']} | "
              f"{r['failures']} | {r['safety_share']:.2%} | {r['mean_return']:.2f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
