"""Learning after deployment (``safeswitch adapt``, issue #40) on the shifts of the shipped
``certified`` policy, deployment seeds 1–3: the frozen policy against the adapting one, under
``certified``.

Shifts (the policy was trained on an ego at 18–25 km/h starting 32–40 m before the conflict
point and an oncoming car at 20–32 km/h; the default is the shift on which the policy shipped
now, frozen, needs the safety action in at least 10 % of episodes, issue #40's condition):

* ``north-fast``: the oncoming car at 38–44 km/h (at 45 km/h some arrivals would start the car
  before its route); the defaults until 2026-12-06 with ``north-slow``, on which the policy
  shipped until 2026-12-01 needed the safety action in at least 10 % of episodes; the policies
  shipped since need none there, and the run shows that adapting leaves such a policy as it is;
* ``north-slow``: the oncoming car at 6–12 km/h (a slow vehicle: it holds the conflict zone
  longer);
* ``ego-close``: the ego starting 22–28 m before the conflict point; ``ego-fast``: the ego
  arriving at 28–30 km/h — on both the throttle-only policies shipped until 2026-12-06 needed
  the safety action in at least 10 % of episodes frozen, and adapting did not help them (a
  throttle cannot brake: docs/adapt.md);
* ``ego-close-fast`` (default): both at once, the ego starting 22–28 m out at 25–30 km/h —
  the one shift on which the ``certified`` policy shipped since 2026-12-06 (its learned action
  brakes too), frozen, needs the safety action in at least 10 % of episodes;
* ``paper-north-fast``: the shipped ``paper`` policy deployed under ``certified``, the oncoming
  car at 36–43 km/h.

Each run deploys ``--episodes`` episodes (default 20,000, the issue's budget: at most 20,000
episodes and 10 minutes) in blocks of ``--block``, with ``--eval-episodes`` held-out scenarios
per evaluation (default 2,000); the table gives, per shift and seed, the collisions while
adapting; the safety-action episodes of the frozen and the adapted policy on unseen scenarios
of the shift, and of the last deployed block; the efficiency, speeding and comfort on the
shift; the original distribution's efficiency and safety actions before and after; the block
whose policy was selected, how many blocks were rolled back and in how many learning was
paused (settled). One torch thread per run; runs go two at a time (two cores). The figure
(the first seed's runs) is written beside the JSON (``--out``).

Run: ``python benchmarks/adapt.py [--episodes 20000]
[--shifts ego-close-fast north-fast north-slow ego-close ego-fast] [--noise STD]
[--noise-decay SHARE] [--rehearsal SHARE] [--no-rollback] [--no-settle] [--n-envs N]
[--eval-episodes N] [--seeds 1 2 3] [--out results/adapt.json]`` (the ``adapt`` options of
the same names, for the ablations of docs/adapt.md; ``--replot results/adapt.json`` redraws
the figure of a saved result).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

import _common

SHIFTS = {
    "ego-close": ("certified", ["env.scenarios.ego_start_distance_m=[22, 28]"]),
    "ego-fast": ("certified", ["env.scenarios.ego_speed_kmh=[28, 30]"]),
    "ego-close-fast": (
        "certified",
        ["env.scenarios.ego_start_distance_m=[22, 28]", "env.scenarios.ego_speed_kmh=[25, 30]"],
    ),
    "north-fast": ("certified", ["env.scenarios.north_speed_kmh=[38, 44]"]),
    "north-slow": ("certified", ["env.scenarios.north_speed_kmh=[6, 12]"]),
    "paper-north-fast": ("paper", ["env.scenarios.north_speed_kmh=[36, 43]"]),
}
DEFAULT_SHIFTS = ["ego-close-fast"]
SEEDS = (1, 2, 3)


def one(job: tuple[str, int, int, int, str, dict[str, Any]]) -> dict[str, object]:
    """One adaptation (in a worker process); ``options``: ``adapt``'s keyword arguments."""
    shift, seed, episodes, block, folder, options = job
    from safeswitch.app.adapt import adapt

    model, settings = SHIFTS[shift]
    summary = adapt(model, Path(folder) / f"{shift}_seed{seed}", settings=settings,
                    episodes=episodes, block=block, seed=seed, **options)  # fmt: skip
    return {**summary, "name": shift, "model": model, "seed": seed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20_000)
    parser.add_argument("--block", type=int, default=1_000)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--noise", type=float, default=None, help="adapt --noise (default: as training ended)"
    )
    parser.add_argument("--noise-decay", type=float, default=None, help="adapt --noise-decay")
    parser.add_argument("--rehearsal", type=float, default=None, help="adapt --rehearsal")
    parser.add_argument("--n-envs", type=int, default=16, help="adapt --n-envs")
    parser.add_argument(
        "--eval-episodes", type=int, default=2_000, help="adapt --eval-episodes (held out, final)"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument(
        "--rollback",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="adapt --rollback / --no-rollback",
    )
    parser.add_argument(
        "--settle",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="adapt --settle / --no-settle",
    )
    parser.add_argument("--shifts", nargs="+", choices=sorted(SHIFTS), default=DEFAULT_SHIFTS)
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--replot", type=Path, help="redraw the figure of a saved result (no adaptation run)"
    )
    args = parser.parse_args()
    if args.replot is not None:
        import json

        from safeswitch.report.figures import adaptation_figure

        saved = json.loads(args.replot.read_text(encoding="utf-8"))
        first = [r for r in saved["runs"] if r["seed"] == args.seeds[0]]
        adaptation_figure(first, args.replot.with_suffix(".png"))
        return
    with tempfile.TemporaryDirectory() as tmp:
        options = {"noise": args.noise, "noise_decay": args.noise_decay,
                   "rehearsal": args.rehearsal, "rollback": args.rollback, "settle": args.settle,
                   "n_envs": args.n_envs, "eval_episodes": args.eval_episodes}  # fmt: skip
        jobs = [
            (s, seed, args.episodes, args.block, tmp, options)
            for s in args.shifts
            for seed in args.seeds
        ]
        with _common.pool(2) as pool:
            futures = {pool.submit(one, job): job for job in jobs}
            for future in as_completed(futures):  # a run takes minutes: say when each ends
                shift, seed = futures[future][:2]
                wall = future.result()["wall_time_s"]
                print(f"{shift}, seed {seed}: adapted in {wall:.0f} s", file=sys.stderr, flush=True)
            runs = [future.result() for future in futures]  # in the jobs' order
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
            "selected_block": run["selected_block"],
            "rolled_back": sum(b["rolled_back"] for b in run["blocks"]),
            "settled_blocks": sum(b["settled"] for b in run["blocks"]),
            "shift_safety": [shifted["frozen"]["safety_activation_episodes"],
                             shifted["adapted"]["safety_activation_episodes"]],
            "wall_time_s": run["wall_time_s"],
        })  # fmt: skip
    result = {"machine": _common.machine(), "episodes": args.episodes, "block": args.block,
              "options": options, "rows": rows, "runs": runs}  # fmt: skip
    if args.out is not None:
        from safeswitch.report.figures import adaptation_figure

        first = [r for r in runs if r["seed"] == args.seeds[0]]
        adaptation_figure(first, args.out.with_suffix(".png"))
    if not _common.publish(result, args.out, args.json):
        print("shift             seed  collisions  safety on the shift: frozen → adapted; last "
              "block deployed  efficiency on the shift  speeding, comfort on the shift  "
              "original: efficiency, safety  selected block (rollbacks; settled)  "
              "wall")  # fmt: skip
        for r in rows:
            e, o, s = r["shift_efficiency"], r["original_efficiency"], r["original_safety"]
            h = r["shift_safety"]
            print(
                f"{r['shift']:<17} {r['seed']:>4}  {r['collisions']:>10}  "
                f"{h[0]:>4} → {h[1]:>4} of {args.eval_episodes:,}; {r['last_block_safety']:>4} of "
                f"{r['last_block_episodes']:,}   {e[0]:.3f} → {e[1]:.3f}   "
                f"{r['shift_speeding'][0]} → {r['shift_speeding'][1]}, "
                f"{r['shift_comfort'][0]:.2%} → {r['shift_comfort'][1]:.2%}   "
                f"{o[0]:.3f} → {o[1]:.3f}, {s[0]} → {s[1]}   {r['selected_block']} "
                f"({r['rolled_back']}; {r['settled_blocks']})  {r['wall_time_s']:.0f} s"
            )


if __name__ == "__main__":
    main()
