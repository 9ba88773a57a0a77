"""Where the left-turn policies lose efficiency against the oracle, by the north car's arrival
offset (issue #39; docs/learning_experiments.md, "Where the `certified` policy's efficiency
goes").

A one-off probe: `safeswitch evaluate` of the oracle and of each shipped left-turn policy on the
1,000 unseen scenarios of seed 1000003 (each under the logic it is deployed with), then, per band
of the arrival offset (how much later than the ego the north car would reach the conflict zone,
as the scenarios draw it), the share of scenarios the oracle passes first in, and each policy's
cuts, never-cleared scenarios, mean efficiency and share of the total loss (``1 - efficiency``
summed over the band, over 1,000). No training.

Run: ``python experiments/probe_certified_bands.py [--models certified paper]`` (one core,
about 15 seconds); ``--out FILE`` writes the table as JSON.
"""

import argparse
import contextlib
import csv
import io
import itertools
import tempfile
from pathlib import Path

import numpy as np

from safeswitch.cli import main as cli
from safeswitch.evaluation.oracle import efficiency
from safeswitch.io import write_json
from safeswitch.leftturn.config import LeftTurnConfig

#: Band edges of the arrival offset [s]: benchmarks/certified_ceiling.py's ``OFFSET_EDGES``,
#: so that the two tables of the learning log line up.
EDGES = (-10.0, -1.0, 1.0, 2.0, 2.5, 3.0, 3.5, 10.0)
EPISODES, SEED = 1000, 1_000_003


def episodes(args: list[str], out: Path) -> dict[str, np.ndarray]:
    """``safeswitch evaluate ARGS`` on the probe's scenarios; its ``episodes.csv`` as columns."""
    with contextlib.redirect_stdout(io.StringIO()):  # its summary: the table below has it
        status = cli(["evaluate", *args, "--episodes", str(EPISODES), "--seed", str(SEED),
                      "--scenarios", "random", "--out", str(out)])  # fmt: skip
    if status != 0:
        raise SystemExit(f"safeswitch evaluate {' '.join(args)} exited with {status}")
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    return {key: np.array([r[key] for r in rows]) for key in rows[0]}


def number(column: np.ndarray) -> np.ndarray:
    """A CSV column as floats (an empty cell: NaN)."""
    return np.array([float(x) if x not in ("", "nan") else np.nan for x in column])


def scenario_efficiency(run: dict[str, np.ndarray]) -> np.ndarray:
    """Each scenario's efficiency as the evaluation counts it (never cleared: the horizon)."""
    horizon = LeftTurnConfig().episode.horizon_s
    return efficiency(
        number(run["oracle_time_to_clear_s"]), number(run["time_to_clear_s"]), horizon
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["certified", "paper"])
    parser.add_argument("--out", type=Path, help="write the table as JSON")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        oracle = episodes(["--controller", "oracle"], Path(tmp) / "oracle")
        runs = {m: episodes(["--model", m], Path(tmp) / m) for m in args.models}
    offset = number(oracle["arrival_offset_s"])
    oracle_cuts = oracle["outcome"] == "cut"
    table: list[dict[str, object]] = []
    header = f"{'offset [s]':>13} {'n':>4} {'oracle cuts':>11}"
    for m in args.models:
        header += f" | {m}: cuts, never, efficiency, loss"
    print(header)
    for run in runs.values():  # the same scenarios
        assert np.array_equal(number(run["arrival_offset_s"]), offset)
    effs = {m: scenario_efficiency(run) for m, run in runs.items()}
    for low, high in itertools.pairwise(EDGES):
        band = (offset >= low) & (offset < high)
        row: dict[str, object] = {"offset_s": [low, high], "scenarios": int(band.sum()),
                                  "oracle_cuts": int(oracle_cuts[band].sum())}  # fmt: skip
        line = f"{low:>5.1f} – {high:>5.1f} {band.sum():>4} {oracle_cuts[band].sum():>11}"
        for m, run in runs.items():
            eff = effs[m]
            cuts = int((run["outcome"][band] == "cut").sum())
            never = int((run["outcome"][band] == "never_cleared").sum())
            loss = float(np.nansum(1.0 - eff[band]) / EPISODES)
            row[m] = {"cuts": cuts, "never_cleared": never,
                      "efficiency": float(np.nanmean(eff[band])), "loss": loss}  # fmt: skip
            line += f" | {cuts:>4} {never:>3} {np.nanmean(eff[band]):.3f} {loss:.4f}"
        table.append(row)
        print(line)
    totals = {}
    for m, run in runs.items():
        totals[m] = {
            "efficiency": float(np.nanmean(effs[m])),
            "collisions": int(number(run["collision"]).sum()),
            "lost_control": int(number(run["lost_control"]).sum()),
            "speeding_episodes": int((number(run["speeding_steps"]) > 0).sum()),
            "comfort_violation_episodes": int((number(run["comfort_violation_steps"]) > 0).sum()),
        }
        print(f"{m}: " + ", ".join(f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}"
                                   for k, v in totals[m].items()))  # fmt: skip
    if args.out:
        write_json(args.out, {"episodes": EPISODES, "seed": SEED, "totals": totals,
                              "bands": table})  # fmt: skip


if __name__ == "__main__":
    main()
