"""Learning after deployment (``safeswitch adapt``, issue #40) on two shifts, deployment seeds
1–3: the frozen shipped policy against the adapting one, under ``certified``.

Shifts (each one where the frozen policy needs the safety action in at least 10 % of
episodes):

* ``ego-fast``: the shipped ``certified`` policy, the ego arriving at 28–30 km/h (trained on
  18–25 km/h);
* ``north-fast``: the shipped ``paper`` policy deployed under ``certified``, the oncoming car at
  36–43 km/h (trained on 20–32 km/h; at 45 km/h some arrivals would start the car before its
  route).

Each run deploys ``--episodes`` episodes in blocks of ``--block`` (the issue's budget: at most
20,000 episodes and 10 minutes); the table gives, per shift and seed, the collisions while
adapting, the safety-action episodes of the last block and of the frozen policy (held-out
scenarios), the efficiency on the shift, and the original distribution's before and after.
One torch thread per run; runs go two at a time (two cores). The figure is written beside
the JSON (``--out``).

Run: ``python benchmarks/adapt.py [--episodes 5000] [--shifts ego-fast north-fast] [--noise STD]
[--out results/adapt.json]`` (``--noise``: ``adapt --noise``, the exploration noise while
deployed; ``--replot results/adapt.json`` redraws the figure of a saved result).
"""

from __future__ import annotations

import argparse
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import _common

SHIFTS = {
    "ego-fast": ("certified", ["env.scenarios.ego_speed_kmh=[28, 30]"]),
    "north-fast": ("paper", ["env.scenarios.north_speed_kmh=[36, 43]"]),
}
SEEDS = (1, 2, 3)


def one(job: tuple[str, int, int, int, str, float | None]) -> dict[str, object]:
    """One adaptation (in a worker process)."""
    shift, seed, episodes, block, folder, noise = job
    from safeswitch.app.adapt import adapt

    model, settings = SHIFTS[shift]
    summary = adapt(model, Path(folder) / f"{shift}_seed{seed}", settings=settings,
                    episodes=episodes, block=block, seed=seed, noise=noise)  # fmt: skip
    return {**summary, "name": shift, "model": model, "seed": seed, "noise": noise}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=5_000)
    parser.add_argument("--block", type=int, default=1_000)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--noise", type=float, default=None, help="adapt --noise (default: as training ended)"
    )
    parser.add_argument("--shifts", nargs="+", choices=sorted(SHIFTS), default=list(SHIFTS))
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--replot", type=Path, help="redraw the figure of a saved result (no adaptation run)"
    )
    args = parser.parse_args()
    if args.replot is not None:
        import json

        from safeswitch.report.figures import adaptation_figure

        saved = json.loads(args.replot.read_text(encoding="utf-8"))
        first = [r for r in saved["runs"] if r["seed"] == SEEDS[0]]
        adaptation_figure(first, args.replot.with_suffix(".png"))
        return
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [
            (s, seed, args.episodes, args.block, tmp, args.noise)
            for s in args.shifts
            for seed in SEEDS
        ]
        with ProcessPoolExecutor(2) as pool:
            runs = list(pool.map(one, jobs))
    rows = []
    for run in runs:
        last = run["blocks"][-1]
        shifted, original = run["shifted"], run["original"]
        rows.append({
            "shift": run["name"], "model": run["model"], "seed": run["seed"],
            "collisions": run["collisions"], "failures": run["failures"],
            "frozen_safety_held_out": run["frozen_held_out"]["safety_activation_episodes"],
            "last_block_safety": last["safety_activation_episodes"],
            "last_block_held_out_safety": last["held_out"]["safety_activation_episodes"],
            "last_block_episodes": last["episodes"],
            "shift_efficiency": [shifted["frozen"]["mean_efficiency"],
                                 shifted["adapted"]["mean_efficiency"]],
            "original_efficiency": [original["frozen"]["mean_efficiency"],
                                    original["adapted"]["mean_efficiency"]],
            "original_safety": [original["frozen"]["safety_activation_episodes"],
                                original["adapted"]["safety_activation_episodes"]],
            "shift_speeding": [shifted["frozen"]["speeding_episodes"],
                               shifted["adapted"]["speeding_episodes"]],
            "shift_comfort": [shifted["frozen"]["comfort_violation_fraction"],
                              shifted["adapted"]["comfort_violation_fraction"]],
            "shift_failures": [shifted["frozen"]["failures"], shifted["adapted"]["failures"]],
            "last_block_speeding": last["speeding_episodes"],
            "wall_time_s": run["wall_time_s"],
        })  # fmt: skip
    result = {"machine": _common.machine(), "episodes": args.episodes, "block": args.block,
              "noise": args.noise, "rows": rows, "runs": runs}  # fmt: skip
    if args.out is not None:
        from safeswitch.report.figures import adaptation_figure

        first = [r for r in runs if r["seed"] == SEEDS[0]]
        adaptation_figure(first, args.out.with_suffix(".png"))
    if not _common.publish(result, args.out, args.json):
        print("shift       seed  collisions  safety (frozen → last block, held out; deployed)"
              "  efficiency on shift  speeding, comfort on shift  original: efficiency, safety"
              "  wall")  # fmt: skip
        for r in rows:
            e, o, s = r["shift_efficiency"], r["original_efficiency"], r["original_safety"]
            print(
                f"{r['shift']:<11} {r['seed']:>4}  {r['collisions']:>10}  "
                f"{r['frozen_safety_held_out']:>4} → {r['last_block_held_out_safety']:>4} of 1,000;"
                f" {r['last_block_safety']:>4} of {r['last_block_episodes']:,}"
                f"   {e[0]:.3f} → {e[1]:.3f}   {r['shift_speeding'][0]} → "
                f"{r['shift_speeding'][1]}, {r['shift_comfort'][0]:.2%} → "
                f"{r['shift_comfort'][1]:.2%}   {o[0]:.3f} → {o[1]:.3f}, {s[0]} → {s[1]}"
                f"  {r['wall_time_s']:.0f} s"
            )


if __name__ == "__main__":
    main()
