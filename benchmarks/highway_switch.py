"""The paper's claim on a second plant: PPO on highway-env with and without the switch.

``safeswitch/Highway-v0`` (highway-env's ``highway-fast-v0``, continuous acceleration and
steering) is trained with PPO (the paper's Table II, 4 environments) under a switching logic
(``certified`` by default) with ``R_ADAS = -1`` and without any logic, with the same seeds.
Reported per run: crashes and off-road departures during training, the share of steps on which
the Safety controller acted (early vs late in training: the penalty should teach the policy not
to need it), episode returns, and a final deterministic evaluation (seed 1000003). Then the
floor: highway-env's own IDM/MOBIL driver in the ego's seat under the same logic (how often a
competent driver that knows nothing of the logic meets the Safety controller), and the
wrapper's own cost on a highway-env step.

The evaluation also reports why the Safety controller acted (the logic's reasons) and how the
policy drove: the steps above the lane's speed limit (30 m/s) and beyond the comfort limits
(|a_lon| ≤ 5, |a_lat| ≤ 3 m/s²) and closer than 1 s to the vehicle ahead: the plant's
``speeding``, ``comfort`` and ``following`` costs (``--reevaluate --keep DIR`` evaluates again
the kept policies of runs recorded before one of them existed, and trains again, with its seed,
such a run whose policy was not kept, saying whether it reproduces what was recorded).
``--imitation W`` adds runs under the first logic that also learn from the Safety controller's
interventions (``policy.intervention_imitation: W``), to set against the penalty alone.

``--config highway`` trains the shipped recipe instead (the learned steering limited, the
comfort cost a constraint; ``src/safeswitch/configs/highway.yaml``) for both logics. Every run
sets the imitation weight itself (0 unless ``--imitation``): the runs named after the logic
alone learn from ``R_ADAS`` alone even where the recipe learns from the interventions too, as
the shipped ``highway`` recipe does (its runs are ``certified+imitation`` with ``--imitation
1``).

Run: ``python benchmarks/highway_switch.py [--config NAME] [--logics certified none]
[--timesteps N] [--seeds 1 2 3] [--imitation W [--imitation-only]] [--parallel 2]
[--eval-episodes 50] [--out FILE] [--keep DIR] [--resume] [--reevaluate] [--figure-only]
[--json]``; writes
``benchmarks/results/highway.json`` and ``docs/highway_training.png``. One torch thread per
run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

import _common
import safeswitch
from safeswitch.cli import main as safeswitch_cli
from safeswitch.examples.highway_drivers import IDMDriver, drive
from safeswitch.io import write_json
from safeswitch.training import train
from safeswitch.training.config import EnvPPOConfig, EnvTrainConfig, load_env_config

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "highway.json"
FIGURE = ROOT / "docs" / "highway_training.png"


#: Without ``--config``: PPO as the paper's Table II (the recorded 200,000-step runs), not a
#: plant's default section.
TABLE_II = EnvPPOConfig(learning_rate=2.5e-4, gae_lambda=0.9, n_epochs=4)


class Episodes(BaseCallback):
    """Every finished episode of a run: timestep, return, crash, off-road, safety steps."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, float]] = []
        self._safety: np.ndarray | None = None

    def _on_step(self) -> bool:
        infos, dones = self.locals["infos"], self.locals["dones"]
        if self._safety is None:
            self._safety = np.zeros(len(infos))
        for i, info in enumerate(infos):
            self._safety[i] += bool(info.get("safety_active", False))
            if dones[i]:
                self.rows.append(
                    {
                        "timestep": self.num_timesteps,
                        "return": float(info["episode"]["r"]),
                        "length": int(info["episode"]["l"]),
                        "crashed": bool(info.get("crashed", False)),
                        "off_road": info["rewards"]["on_road_reward"] == 0,
                        "safety_steps": float(self._safety[i]),
                    }
                )
                self._safety[i] = 0
        return True


def run_name(switching: str, imitation: float) -> str:
    """A run's method: the logic, ``+imitation`` when it learns from the interventions."""
    return f"{switching}+imitation" if imitation else switching


def run_key(run: dict[str, Any]) -> tuple[str, float, int]:
    """What names a run: its logic, imitation weight and seed."""
    return run["switching"], run["imitation"], run["seed"]


def methods(
    logics: list[str], imitation: float = 0.0, imitation_only: bool = False
) -> list[tuple[str, float]]:
    """The (logic, imitation weight) pairs to train: each logic with R_ADAS alone, and with
    ``imitation`` the first logic with the fit too — instead of alone with ``imitation_only``."""
    wanted = [(logic, 0.0) for logic in logics]
    if imitation:
        wanted.append((logics[0], imitation))
        if imitation_only:
            wanted.remove((logics[0], 0.0))
    return wanted


def kept_dir(keep: Path, switching: str, imitation: float, seed: int) -> Path:
    return keep / f"{run_name(switching, imitation).replace('+', '_')}_seed{seed}"


def train_one(
    switching: str,
    seed: int,
    timesteps: int,
    eval_episodes: int,
    keep: Path | None = None,
    imitation: float = 0.0,
    recipe: str | None = None,
) -> dict[str, object]:
    torch.set_num_threads(1)
    base = (
        load_env_config(recipe)
        if recipe
        else EnvTrainConfig(env_id=safeswitch.HIGHWAY_ENV_ID, penalty=-1.0, ppo=TABLE_II)
    )
    config = replace(
        base,
        switching=switching,
        timesteps=timesteps,
        n_envs=4,
        seed=seed,
        torch_threads=1,
        checkpoint_every=10 * timesteps,
        eval_episodes=eval_episodes,
        policy=replace(base.policy, intervention_imitation=imitation),
    )
    episodes = Episodes()
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = kept_dir(keep, switching, imitation, seed) if keep else Path(tmp) / "run"
        metrics = train(config, run_dir, progress_bar=False, callbacks=[episodes])
    rows = episodes.rows
    steps = np.array([r["length"] for r in rows], dtype=float)
    safety = np.array([r["safety_steps"] for r in rows])
    when = np.array([r["timestep"] for r in rows])
    early, late = when <= 0.2 * timesteps, when > 0.8 * timesteps

    def rate(mask: np.ndarray) -> float:
        return float(safety[mask].sum() / max(steps[mask].sum(), 1))

    def mean_return(mask: np.ndarray) -> float:
        return float(np.mean([r["return"] for r, m in zip(rows, mask, strict=True) if m]))

    return {
        "switching": switching,
        "imitation": imitation,
        "seed": seed,
        "timesteps": metrics["timesteps"],
        "wall_time_s": metrics["wall_time_s"],
        "episodes": len(rows),
        "crashes": int(sum(r["crashed"] for r in rows)),
        "off_road": int(sum(r["off_road"] for r in rows)),
        "safety_rate_first_20pct": rate(early),
        "safety_rate_last_20pct": rate(late),
        "return_first_20pct": mean_return(early),
        "return_last_20pct": mean_return(late),
        "evaluation": metrics["evaluation"],
        "curve": [
            {
                "timestep": int(r["timestep"]),
                "return": r["return"],
                "safety_rate": r["safety_steps"] / max(r["length"], 1),
                "failure": bool(r["crashed"] or r["off_road"]),
            }
            for r in rows
        ],
    }


def reevaluate(run: dict[str, Any], keep: Path, episodes: int) -> dict[str, Any]:
    """The kept policy of ``run`` evaluated again the way training evaluated it (``safeswitch
    evaluate``, same seed and episodes): the reasons and driving costs for runs recorded
    before they were."""
    torch.set_num_threads(1)
    model = kept_dir(keep, *run_key(run))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "evaluation"
        code = safeswitch_cli(
            ["evaluate", "--env", safeswitch.HIGHWAY_ENV_ID, "--model", str(model),
             "--episodes", str(episodes), "--seed", str(run["evaluation"]["seed"]),
             "--out", str(out)]
        )  # fmt: skip
        if code:
            raise RuntimeError(f"safeswitch evaluate --model {model} exited with {code}")
        summary = json.loads((out / "summary.json").read_text())
    fields = (*run["evaluation"], "safety_reasons", "cost_steps", "safety_cost_steps")
    return {k: summary[k] for k in fields if k in summary}


def idm_floor(switching: str, episodes: int, seed: int = 1_000_003) -> dict[str, Any]:
    """highway-env's IDM/MOBIL driver in the ego's seat under ``switching``, on the trained
    policies' evaluation episodes."""
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching=switching)
    row = drive(env, IDMDriver(), episodes, seed)
    env.close()
    return {"switching": switching, **row}


def wrapper_overhead(steps: int = 600, rounds: int = 5) -> dict[str, float]:
    """Time per step of the raw highway-env environment and of the same environment inside
    SafeSwitch with the ``none`` logic (same trajectory: state read-out, Safety controller and
    supervision are the overhead) and with ``ttc``; interleaved rounds, medians."""
    import highway_env  # noqa: F401

    from safeswitch.examples.highway import HIGHWAY_CONFIG

    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 2)).astype(np.float32)
    makers = {
        "raw": lambda: gym.make("highway-fast-v0", config=HIGHWAY_CONFIG),
        "safeswitch_none": lambda: gym.make(safeswitch.HIGHWAY_ENV_ID, switching="none"),
        "safeswitch_ttc": lambda: gym.make(safeswitch.HIGHWAY_ENV_ID, switching="ttc"),
        "safeswitch_certified": lambda: gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified"),
    }
    times: dict[str, list[float]] = {name: [] for name in makers}
    for _ in range(rounds):
        for name, make in makers.items():
            env = make()
            env.reset(seed=0)
            start = time.perf_counter()
            for action in actions:
                *_, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset(seed=0)
            times[name].append((time.perf_counter() - start) / steps)
            env.close()
    out = {f"{name}_ms_per_step": 1e3 * statistics.median(v) for name, v in times.items()}
    paired = [w / r for w, r in zip(times["safeswitch_none"], times["raw"], strict=True)]
    out["none_over_raw"] = statistics.median(paired) - 1.0
    return out


def ordered(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The runs by method (switched before unswitched, with imitation after without) and
    seed, whatever order they were trained or back-filled in."""
    return sorted(runs, key=lambda r: (r["switching"] == "none", r["switching"],
                                       r["imitation"], r["seed"]))  # fmt: skip


def figure(runs: list[dict[str, Any]], path: Path, recipe: str | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    fig, axes = plt.subplots(1, 3, figsize=(15, 4), constrained_layout=True)
    colours = {"certified": "tab:green", "ttc": "tab:blue", "none": "tab:red"}
    for run in ordered(runs):
        curve = run["curve"]
        assert isinstance(curve, list)
        t = np.array([c["timestep"] for c in curve])
        name = run_name(str(run["switching"]), float(run["imitation"]))  # type: ignore[arg-type]
        label = f"{name} (seed {run['seed']})"
        style = {
            "color": "tab:purple" if name.endswith("+imitation") else colours[name],
            "linestyle": ("-", "--", ":")[(int(run["seed"]) - 1) % 3],  # type: ignore[call-overload]
            "alpha": 0.8,
            "label": label,
        }
        window = 25
        for ax, key in ((axes[0], "safety_rate"), (axes[1], "return"), (axes[2], "failure")):
            values = np.array([float(c[key]) for c in curve])
            if values.size >= window:
                smooth = np.convolve(values, np.ones(window) / window, mode="valid")
                ax.plot(t[window - 1 :], smooth, **style)
    axes[0].set_ylabel("share of steps the Safety controller acted")
    axes[1].set_ylabel("episode return (penalty included)")
    axes[2].set_ylabel("episodes ending in a crash or off the road")
    for ax in axes:
        ax.set_xlabel("training timesteps")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:.0f}k"))
    axes[2].legend(fontsize=7)  # one legend, where the curves leave room
    logics = " / ".join(
        sorted({run_name(str(r["switching"]), float(r["imitation"])) for r in runs}  # type: ignore[arg-type]
               - {"none"})
    )  # fmt: skip
    how = f"the '{recipe}' recipe" if recipe else "PPO as Table II, full steering range"
    fig.suptitle(
        f"PPO on {safeswitch.HIGHWAY_ENV_ID} ({how}): with the {logics} switch vs without "
        "(25-episode means)"
    )
    path.parent.mkdir(exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def reasons(evaluation: dict[str, Any]) -> str:
    """``leader 162, off_road 26, …``: the Safety controller's steps by the logic's reason."""
    counts = evaluation.get("safety_reasons")
    if counts is None:
        return "not recorded"
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "—"


#: The plant's named costs the table shows, in its order (``following``: closer than 1 s to the
#: vehicle ahead; runs recorded before it existed show "—" until ``--reevaluate``).
DRIVING_COSTS = ("speeding", "comfort", "following")


def driving(evaluation: dict[str, Any]) -> str:
    """``0 / 86 (60) / 243 (83) of 7,550``: the evaluation steps above the speed limit / beyond
    comfort / closer than 1 s to the vehicle ahead (in brackets: of those, the steps the Safety
    controller drove)."""
    costs = evaluation.get("cost_steps")
    if costs is None:
        return "not recorded"
    by_safety = evaluation.get("safety_cost_steps") or {}
    shown = []
    for name in DRIVING_COSTS:
        if name not in costs:
            shown.append("—")
            continue
        mine = f" ({by_safety[name]})" if name in by_safety else ""
        shown.append(f"{costs[name]}{mine}")
    return f"{' / '.join(shown)} of {evaluation['steps']:,}"


def stale(evaluation: dict[str, Any]) -> bool:
    """The evaluation was recorded before the Safety controller's share of each cost, or before
    one of :data:`DRIVING_COSTS`, was (``--reevaluate`` evaluates it again)."""
    costs = evaluation.get("cost_steps")
    return (
        costs is None
        or "safety_cost_steps" not in evaluation
        or any(name not in costs for name in DRIVING_COSTS)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logics", nargs="+", default=["certified", "none"])
    parser.add_argument("--timesteps", type=int, default=200_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument(
        "--config", default=None,
        help="the recipe: a highway-env training configuration (e.g. the shipped 'highway'); "
             "its switching, seed, budget and evaluation are this script's (default: PPO's "
             "defaults on highway-env's full steering range, no constraint)",
    )  # fmt: skip
    parser.add_argument(
        "--imitation", type=float, default=0.0,
        help="also train the first logic with policy.intervention_imitation W (runs "
             "'LOGIC+imitation')",
    )  # fmt: skip
    parser.add_argument(
        "--imitation-only", action="store_true",
        help="with --imitation: train the first logic only with the fit (the runs of a recipe "
             "whose own weight it is), not also with R_ADAS alone",
    )  # fmt: skip
    parser.add_argument("--parallel", type=int, default=2, help="training runs at once")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--figure", type=Path, default=FIGURE)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--keep", type=Path, default=None,
        help="keep each run's directory (model, metrics, TensorBoard) as KEEP/LOGIC_seedN",
    )  # fmt: skip
    parser.add_argument(
        "--resume", action="store_true",
        help="keep the runs --out already holds (same budget) and train only the missing ones",
    )  # fmt: skip
    parser.add_argument(
        "--reevaluate", action="store_true",
        help="evaluate again the kept policies (--keep) of runs recorded without the reasons "
             "and every driving cost (and who drove them); such a run not kept is trained again",
    )  # fmt: skip
    parser.add_argument(
        "--figure-only", action="store_true", help="draw the figure from --out and stop"
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.imitation_only and not args.imitation:
        parser.error("--imitation-only needs --imitation W")
    if args.figure_only:
        kept = json.loads(args.out.read_text())
        figure(kept["runs"], args.figure, kept.get("recipe"))
        return 0
    torch.set_num_threads(1)
    result: dict[str, Any] = {
        "benchmark": "highway_switch",
        **_common.machine(),
        "timesteps": args.timesteps,
        "eval_episodes": args.eval_episodes,
        "recipe": args.config,
        "runs": [],
    }
    if args.resume and args.out.exists():
        kept = json.loads(args.out.read_text())
        same = (args.timesteps, args.eval_episodes, args.config)
        if (kept["timesteps"], kept["eval_episodes"], kept.get("recipe")) == same:
            result["runs"] = kept["runs"]
    runs: list[dict[str, Any]] = result["runs"]
    if args.reevaluate and args.keep is None:
        parser.error("--reevaluate evaluates the kept policies: pass --keep DIR")
    again = [r for r in runs if args.reevaluate and stale(r["evaluation"])]
    # A stale run whose policy was not kept is trained again (the runs are deterministic on one
    # machine: seed 1 of the recipe reproduced its model and evaluation bit for bit); what it
    # recorded before is checked against the new run.
    previous: dict[tuple[str, float, int], dict[str, Any]] = {}
    for run in [r for r in again if args.keep is not None]:
        if not (kept_dir(args.keep, *run_key(run)) / "model.zip").is_file():
            previous[run_key(run)] = run
            again.remove(run)
            runs.remove(run)
    for run in [r for r in again if r["evaluation"]["safety_activation_steps"] == 0]:
        costs = run["evaluation"].get("cost_steps") or {}
        if all(name in costs for name in DRIVING_COSTS):  # the Safety controller never drove
            run["evaluation"]["safety_cost_steps"] = dict.fromkeys(
                run["evaluation"]["cost_steps"], 0
            )
            again.remove(run)
    done = {run_key(r) for r in runs}
    wanted = methods(args.logics, args.imitation, args.imitation_only)
    jobs = [(lg, w, seed) for seed in args.seeds for lg, w in wanted if (lg, w, seed) not in done]
    with _common.pool(args.parallel) as pool:
        evaluations = [pool.submit(reevaluate, run, args.keep, args.eval_episodes) for run in again]
        futures = [
            pool.submit(
                train_one,
                logic,
                seed,
                args.timesteps,
                args.eval_episodes,
                args.keep,
                weight,
                args.config,
            )
            for logic, weight, seed in jobs
        ]
        for run, evaluation in zip(again, evaluations, strict=True):
            run["evaluation"] = evaluation.result()
            write_json(args.out, result)
        for future in futures:
            run = future.result()
            runs.append(run)
            before = previous.get(run_key(run))
            if before is not None:
                same = all(
                    run["evaluation"][k] == v
                    for k, v in before["evaluation"].items()
                    if k in ("failures", "safety_activation_steps", "mean_return", "steps")
                ) and (before["crashes"], before["episodes"]) == (run["crashes"], run["episodes"])
                print(
                    f"{run_name(run['switching'], run['imitation'])} seed {run['seed']} trained "
                    f"again: {'reproduces' if same else 'DIFFERS FROM'} its recorded run",
                    file=sys.stderr,
                    flush=True,
                )
            write_json(args.out, result)  # each run is kept the moment it ends (--resume)
            print(
                f"{run_name(run['switching'], run['imitation']):19} seed {run['seed']}: "
                f"{run['episodes']} episodes, crashes "
                f"{run['crashes']}, off road {run['off_road']}, safety rate "
                f"{run['safety_rate_first_20pct']:.3f} → {run['safety_rate_last_20pct']:.3f}, "
                f"return {run['return_first_20pct']:.1f} → {run['return_last_20pct']:.1f} "
                f"({run['wall_time_s']:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
    result["idm_driver"] = [idm_floor(logic, args.eval_episodes) for logic in args.logics]
    result["wrapper_overhead"] = wrapper_overhead()
    floors = result["idm_driver"]
    write_json(args.out, result)
    figure(runs, args.figure, args.config)
    if args.json:
        _common.emit({k: v for k, v in result.items() if k != "runs"}, True)
        return 0
    unswitched = {
        r["seed"]: r["evaluation"]["mean_return"] for r in runs if r["switching"] == "none"
    }
    print("| method | seed | training: crashes / off road / episodes | safety share, first → "
          "last 20 % | evaluation: crashes | safety share | why (steps) | speeding / comfort / "
          "under 1 s behind, steps (the Safety controller's) | mean return | "
          "of none's |")  # fmt: skip
    print("| --- | ---: | --- | --- | ---: | ---: | --- | --- | ---: | ---: |")
    for r in ordered(runs):
        e = r["evaluation"]
        assert isinstance(e, dict)
        base = unswitched.get(r["seed"])
        ratio = f"{e['mean_return'] / base:.3f}" if base else "—"
        print(
            f"| {run_name(r['switching'], r['imitation'])} | {r['seed']} | "
            f"{r['crashes']} / {r['off_road']} / {r['episodes']} | "
            f"{r['safety_rate_first_20pct']:.3f} → {r['safety_rate_last_20pct']:.3f} | "
            f"{e['failures']} | {e['safety_share']:.4f} | {reasons(e)} | {driving(e)} | "
            f"{e['mean_return']:.1f} | {ratio} |"
        )
    for f in floors:
        print(
            f"IDM/MOBIL driver under {f['switching']}: {f['crashes']} crashes, {f['off_road']} "
            f"off road in {f['episodes']}, safety share {f['safety_share']:.4f} "
            f"({reasons(f)}), speeding / comfort / under 1 s behind steps {driving(f)}, "
            f"mean return {f['mean_return']:.1f}"
        )
    o = result["wrapper_overhead"]
    print(
        f"step: raw {o['raw_ms_per_step']:.2f} ms, SafeSwitch(none) "
        f"{o['safeswitch_none_ms_per_step']:.2f} ms ({100 * o['none_over_raw']:+.1f} %), "
        f"SafeSwitch(ttc) {o['safeswitch_ttc_ms_per_step']:.2f} ms, SafeSwitch(certified) "
        f"{o['safeswitch_certified_ms_per_step']:.2f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
