"""ONNX parity of every shipped policy (``safeswitch export``, issue #42): the largest
|ONNX − torch| action difference on 100,000 observations of the policy's own evaluation
episodes (seed 1,000,003; the highway-env policies: 10,000), onnxruntime and torch on one
thread each; for a policy with a folded go predictor also the predictor's own difference and
the end-to-end one (``safeswitch.deploy.export.Parity``).

Run: ``python benchmarks/export_parity.py [--observations N] [--highway-observations N]
[--out results/export_parity.json]``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import _common


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--observations", type=int, default=100_000)
    parser.add_argument(
        "--highway-observations", type=int, default=10_000,
        help="for the highway-env policies (a highway-env step takes about 10 ms)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    from safeswitch.deploy.export import export
    from safeswitch.training.shipped import SHIPPED, SHIPPED_DIR

    names = sorted(n for n, f in SHIPPED.items()
                   if n != "shipped" and (SHIPPED_DIR / f / "model.zip").is_file())  # fmt: skip
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            count = args.highway_observations if name.startswith("highway-") else args.observations
            result = export(name, Path(tmp) / name, observations=count)
            rows[name] = {"max_abs_diff": result.max_abs_diff,
                          "observations": result.observations}  # fmt: skip
            if result.parity.go_max_abs_diff is not None:  # a folded go predictor's parts
                rows[name]["go_probability_max_abs_diff"] = result.parity.go_max_abs_diff
                rows[name]["end_to_end_max_abs_diff"] = result.parity.end_to_end_max_abs_diff
    out = {"machine": _common.machine(), "tolerance": 1e-5, "policies": rows}
    if not _common.publish(out, args.out, args.json):
        for name, row in rows.items():
            go = (f" (its go predictor {row['go_probability_max_abs_diff']:.2e}, end to end "
                  f"{row['end_to_end_max_abs_diff']:.2e})" if "end_to_end_max_abs_diff" in row
                  else "")  # fmt: skip
            print(f"{name:>18}: max |ONNX - torch| = {row['max_abs_diff']:.2e} on "
                  f"{row['observations']:,} observations{go}")  # fmt: skip


if __name__ == "__main__":
    main()
