"""The README's evaluation section: ``safeswitch reproduce --quick`` on 1,000 random scenarios
(seed 1000003), its comparison table printed, and the README's two figures copied to ``docs/``.

Usage: ``python benchmarks/report.py [--out DIR]`` (default ``out/report``, whose earlier files
of the report it replaces; one torch thread).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import torch

import _common  # noqa: F401  (pins the numeric libraries to one thread)
from safeswitch.app.reproduce import reproduce

DOCS = Path(__file__).resolve().parent.parent / "docs"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="out/report")
    args = parser.parse_args()
    torch.set_num_threads(1)
    reproduce(args.out, quick=True, episodes=1000, overwrite=True)
    DOCS.mkdir(exist_ok=True)
    for stem in ("comparison", "ppo-paper_cut", "ppo-paper_yield1", "ppo-no-adas_yield1"):
        shutil.copyfile(Path(args.out) / "figures" / f"{stem}.png", DOCS / f"{stem}.png")
    print(f"figures copied to {DOCS}/")


if __name__ == "__main__":
    main()
