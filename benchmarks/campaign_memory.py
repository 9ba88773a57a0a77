"""A campaign of a trillion episodes on a local Ray cluster: how soon its plan is printed, and
its memory over a minute (issue #38: a campaign streams its shards, whatever ``--episodes``).

Runs ``safeswitch campaign --controller rule --episodes 10**12 --workers 2`` for ``--seconds``,
samples every second the resident memory of the command itself and of every process it
started (the Ray services and the workers), then stops it with Ctrl-C.

    python benchmarks/campaign_memory.py [--seconds 60] [--out results/campaign_memory.json]
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import machine, publish


def _tree(root: int) -> list[int]:
    """``root`` and every process below it."""
    listing = subprocess.run(["ps", "-eo", "pid,ppid"], capture_output=True, text=True).stdout
    children: dict[int, list[int]] = {}
    for line in listing.splitlines()[1:]:
        pid, ppid = (int(v) for v in line.split())
        children.setdefault(ppid, []).append(pid)
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo.extend(children.get(pid, []))
    return out


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as handle:
            for line in handle:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        command = [
            sys.executable, "-c",
            "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "from safeswitch.cli import main; sys.exit(main(sys.argv[1:]))",
            "campaign", "--controller", "rule", "--episodes", str(10**12), "--workers",
            str(args.workers), "--json", "--out", str(Path(folder) / "c"),
        ]  # fmt: skip
        started = time.perf_counter()
        child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        plan = child.stderr.readline().strip() if child.stderr else ""
        plan_s = time.perf_counter() - started
        own, tree = [], []
        while time.perf_counter() - started < args.seconds:
            time.sleep(1.0)
            own.append(round(_rss_mb(child.pid), 1))
            tree.append(round(sum(_rss_mb(p) for p in _tree(child.pid)), 1))
        child.send_signal(signal.SIGINT)
        child.wait(timeout=120)
    half = len(own) // 2
    result = {
        "benchmark": "campaign_memory",
        "machine": machine(),
        "workers": args.workers,
        "episodes_asked": 10**12,
        "plan_line": plan,
        "plan_after_s": round(plan_s, 2),
        "seconds": args.seconds,
        "command_rss_mb": {"max": max(own), "first_half_max": max(own[:half]),
                           "second_half_max": max(own[half:])},
        "all_processes_rss_mb": {"max": max(tree), "first_half_max": max(tree[:half]),
                                 "second_half_max": max(tree[half:])},
        "exit_code": child.returncode,
    }  # fmt: skip
    if not publish(result, args.out, args.json):
        print(f"plan after {plan_s:.1f} s: {plan}")
        print(f"the command: at most {max(own):.0f} MB (second half of the run "
              f"{max(own[half:]):.0f} MB)")  # fmt: skip
        print(f"with Ray and its workers: at most {max(tree):.0f} MB (second half "
              f"{max(tree[half:]):.0f} MB)")  # fmt: skip
        print(f"stopped with Ctrl-C: exit code {child.returncode}")


if __name__ == "__main__":
    main()
