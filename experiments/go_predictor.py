"""A learned go/no-go predictor for the left turn in traffic (issue #39;
docs/learning_experiments.md, "A learned go predictor in the observation").

PPO from a random start in traffic loses the early gaps: it stops before the junction where the
gap planner keeps its speed into the first gap its forward simulation accepts. This script
learns that forward simulation's verdict from the observation alone, so that a policy can be
given it as one more observed value:

1. **States.** Random drivers (no planner, no demonstrations: each episode holds a random
   pedal, redrawn with probability 0.3 at each 0.3 s decision, around a random per-episode
   bias) drive training-distribution scenes of a seed no run trains on; every decision of an
   episode still before its first conflict zone is a sample. ``--drivers MODEL`` samples
   instead the states of drivers that go on a predictor's verdict (a threshold and a pedal
   noise drawn per episode): a DAgger-like round for the predictor, still no action labels.
2. **Labels.** From each such state the fast drive (the speed limit plus the tolerated
   speeding, the lateral comfort limit in the turn:
   :class:`~safeswitch.evaluation.planner.FastDrive`) is simulated on a copy of the scene
   under ``certified``, every vehicle as it will drive (those still to come and the yielding
   drivers included): the label is whether it gets past the last conflict zone with no
   collision and without the filter acting — the gap planner's go check
   (:meth:`~safeswitch.evaluation.traffic_planner.GapPlanner.goes`).
3. **Model.** A 2 x 64 tanh MLP (``--hidden``) on the standardised observation, trained with
   the binary cross-entropy; its probability is what the policy is shown (``traffic.go_model``,
   :class:`~safeswitch.leftturn.go_model.GoModel`). The weights are written as an ``.npz`` the
   task reads with numpy.

The model sees only what the policy sees; it knows nothing the policy could not learn, but it
is taught by simulated outcomes of one fixed drive, which PPO's exploration rarely tries whole.

Run: ``python experiments/go_predictor.py --out experiments/go_model.npz`` (one torch thread;
two batches of 1,024 episodes, scene seeds 7001 and 7101, about 4 minutes; ``--data A.npz``
keeps the samples, ``--data A.npz B.npz`` fits on samples kept before).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from io import BytesIO
from pathlib import Path

import numpy as np
import torch

from safeswitch.evaluation.planner_config import GapPlannerConfig
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.io import write_bytes_atomic
from safeswitch.leftturn.go_model import GoModel
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import load_config

CONFIG = "experimental/traffic_certified_time_left_terminal_g997"


class PredictedGo(GapPlanner):
    """The gap planner whose go check is a learned predictor's probability above
    ``threshold`` (a number, or one per episode): its wait and its drive unchanged.

    Args:
        task: The task in traffic.
        threshold: The probability above which it goes.
        probability: The predictor on the task's observation (default: the observation's
            last value, the task's own ``traffic.go_model``).
        config: The gap planner's tuning (its wait and drive; default: the default tuning).
    """

    def __init__(self, task, threshold, probability=None, config=None):
        super().__init__(task, config)
        self.task, self.threshold = task, threshold
        self.probability = probability or (lambda obs: obs[:, -1])

    def goes(self, state, going=None):
        return self.probability(self.task.observe(state)) > self.threshold


class RandomDrivers:
    """The random drivers whose states the predictors are sampled on: each episode a random
    pedal around a random per-episode bias, redrawn with probability 0.3 at each decision."""

    def __init__(self, rng: np.random.Generator, episodes: int) -> None:
        self.rng = rng
        self.bias = rng.uniform(-0.6, 1.0, episodes)
        self.spread = rng.uniform(0.1, 0.8, episodes)
        self.action = self._drawn()

    def _drawn(self) -> np.ndarray:
        return np.clip(self.bias + self.spread * self.rng.standard_normal(len(self.bias)), -1, 1)

    def next(self) -> np.ndarray:
        """The pedals of the next decision."""
        redraw = self.rng.random(len(self.bias)) < 0.3
        self.action = np.where(redraw, self._drawn(), self.action)
        return self.action


def samples(
    config: str,
    seed: int,
    episodes: int,
    model: Path | None = None,
    approach: str = "coast",
    extra: Callable[[LeftTurnTask, object], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observations, labels and episode ids of the decisions before the junction: of random
    drivers, or (``model``) of drivers that go on that predictor's verdict and wait as the gap
    planner's ``approach`` does. ``extra(task, state)``: columns appended to each sample's
    observation (``[B, E]`` for the sampled episodes' ``state``)."""
    cfg = load_config(config)
    task = build_task(None, cfg.env, traffic=cfg.traffic)
    planner = GapPlanner(task)
    rng = np.random.default_rng(seed)
    ids = np.arange(episodes)
    scenes = task.draw_scenarios(seed, ids, np.zeros_like(ids))
    random_drivers = RandomDrivers(rng, episodes)
    rule = None
    if model is not None:  # the predictor's own drivers: a threshold and a pedal noise each
        width = task.observation_bounds[0].shape[0]
        predictor = GoModel(str(model), width, "traffic.go_model")
        tuning = (
            GapPlannerConfig(approach=approach, coast_decel=2.0) if approach == "brake" else None
        )
        rule = PredictedGo(task, rng.uniform(0.2, 0.8, episodes), predictor, tuning)
        noise = rng.uniform(0.0, 0.4, episodes) * (rng.random(episodes) < 0.5)
    live = np.ones(episodes, dtype=bool)
    obs_rows: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    which: list[np.ndarray] = []

    def drive(obs: np.ndarray, state: object, tick: int) -> np.ndarray:
        rows = np.flatnonzero(live & (state.world.progress[:, 0] <= planner.first_entry))
        if rows.size:
            taken = state.take(rows)
            ok = planner.passes(taken)
            columns = [obs[rows]] if extra is None else [obs[rows], extra(task, taken)]
            obs_rows.append(np.concatenate(columns, axis=1))
            labels.append(ok)
            which.append(rows)
        if rule is not None:
            pedal = rule(obs, state, tick) + noise * rng.standard_normal(episodes)
            return np.clip(pedal, -1.0, 1.0)
        return random_drivers.next().astype(np.float64)

    def on_tick(state: object, record: object, tick: int) -> None:
        live[:] &= ~(record.terminated | record.truncated)

    rollout(task, scenes, drive, on_tick)
    return np.concatenate(obs_rows), np.concatenate(labels), np.concatenate(which)


def fit(
    x: np.ndarray, y: np.ndarray, groups: np.ndarray, epochs: int, seed: int, hidden: int = 64
) -> dict:
    """The MLP fitted on 80 % of the episodes, scored on the other 20 %."""
    torch.manual_seed(seed)
    held = np.random.default_rng(seed).random(groups.max() + 1) < 0.2
    test = held[groups]
    mean, std = x[~test].mean(0), x[~test].std(0) + 1e-6
    xs = torch.tensor((x - mean) / std, dtype=torch.float32)
    ys = torch.tensor(y, dtype=torch.float32)
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, hidden),
        torch.nn.Tanh(), torch.nn.Linear(hidden, 1),
    )  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    train_rows = np.flatnonzero(~test)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    shuffle = np.random.default_rng(seed + 1)
    for _ in range(epochs):
        order = shuffle.permutation(train_rows)
        for batch in np.array_split(order, max(1, len(train_rows) // 512)):
            opt.zero_grad()
            loss = loss_fn(net(xs[batch]).squeeze(1), ys[batch])
            loss.backward()
            opt.step()
    with torch.no_grad():
        p = torch.sigmoid(net(xs).squeeze(1)).numpy()
    scores = {}
    for name, rows in (("train", ~test), ("held_out", test)):
        pr, yr = p[rows], y[rows].astype(bool)
        order = np.argsort(pr)
        ranks = np.empty(len(pr))
        ranks[order] = np.arange(1, len(pr) + 1)
        auc = (ranks[yr].sum() - yr.sum() * (yr.sum() + 1) / 2) / max(1, yr.sum() * (~yr).sum())
        scores[name] = {
            "samples": int(rows.sum()),
            "positive_share": float(yr.mean()),
            "accuracy": float(((pr > 0.5) == yr).mean()),
            "auc": float(auc),
            "brier": float(((pr - yr) ** 2).mean()),
            "recall_at_0.5": float((pr[yr] > 0.5).mean()) if yr.any() else None,
            "precision_at_0.5": float(yr[pr > 0.5].mean()) if (pr > 0.5).any() else None,
        }
    layers = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights = {"mean": mean.astype(np.float32), "std": std.astype(np.float32)}
    for i, layer in enumerate(layers):
        weights[f"w{i}"] = layer.weight.detach().numpy().T.astype(np.float32)
        weights[f"b{i}"] = layer.bias.detach().numpy().astype(np.float32)
    return {"scores": scores, "weights": weights}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=CONFIG)
    parser.add_argument(
        "--seed",
        type=int,
        default=7001,
        help="of the scenes and drivers of the first batch (batch b: seed + 100 b)",
    )
    parser.add_argument("--episodes", type=int, default=1024, help="per batch")
    parser.add_argument("--batches", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--hidden", type=int, default=64, help="units per hidden layer")
    parser.add_argument(
        "--drivers",
        type=Path,
        default=None,
        metavar="MODEL",
        help="sample the states of drivers that go on this predictor's verdict "
        "(a threshold and a pedal noise drawn per episode), not random ones",
    )
    parser.add_argument(
        "--approach",
        choices=("coast", "brake"),
        default="coast",
        help="how the predictor's drivers wait: the gap planner's coast, or its braked "
        "approach at 2 m/s² (a scene with a learned brake)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        nargs="*",
        default=[],
        help="sample files (.npz) to reuse if they all exist, else one to write",
    )
    parser.add_argument("--out", type=Path, required=True, help="the model's .npz")
    args = parser.parse_args()
    torch.set_num_threads(1)
    start = time.time()
    seeds = [args.seed + 100 * b for b in range(args.batches)]
    drivers = str(args.drivers) if args.drivers else "random"
    if args.drivers and args.approach != "coast":
        drivers += f" ({args.approach} approach)"
    if args.data and all(p.is_file() for p in args.data):
        loaded = [np.load(p) for p in args.data]
        x = np.concatenate([d["x"] for d in loaded])
        y = np.concatenate([d["y"] for d in loaded])
        offsets = np.cumsum([0] + [int(d["g"].max()) + 1 for d in loaded[:-1]])
        g = np.concatenate([d["g"] + o for d, o in zip(loaded, offsets, strict=True)])
        # Where the samples came from is the files' record, not this command line's.
        sources = [
            {"file": str(p), "scene_seeds": d["seeds"].tolist(), "drivers": str(d["drivers"])}
            if "seeds" in d.files
            else {"file": str(p), "scene_seeds": None, "drivers": "not recorded"}
            for p, d in zip(args.data, loaded, strict=True)
        ]
    else:
        parts = [samples(args.config, seed, args.episodes, args.drivers, args.approach)
                 for seed in seeds]  # fmt: skip
        x = np.concatenate([p[0] for p in parts])
        y = np.concatenate([p[1] for p in parts])
        g = np.concatenate([p[2] + b * args.episodes for b, p in enumerate(parts)])
        if args.data:
            buffer = BytesIO()
            np.savez_compressed(buffer, x=x, y=y, g=g, seeds=seeds, drivers=drivers)
            write_bytes_atomic(args.data[0], buffer.getvalue())
        sources = [{"file": str(args.data[0]) if args.data else None, "scene_seeds": seeds,
                    "drivers": drivers}]  # fmt: skip
    sampled = time.time() - start
    model = fit(x, y, g, args.epochs, args.seed, args.hidden)
    buffer = BytesIO()
    np.savez(buffer, **model["weights"])
    write_bytes_atomic(args.out, buffer.getvalue())
    report = {"config": args.config, "samples": sources, "episodes": int(g.max()) + 1,
              "hidden": args.hidden, "epochs": args.epochs, "sampling_s": round(sampled, 1),
              "scores": model["scores"]}  # fmt: skip
    text = json.dumps(report, indent=2) + "\n"
    print(text, end="")
    write_bytes_atomic(args.out.with_suffix(".json"), text.encode())


if __name__ == "__main__":
    main()
