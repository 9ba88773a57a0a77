"""Record the learned runs of ``leftturn_golden_pre_friction.npz`` again, on code from before
the friction circle, with the portable learned controller (``portable.py``).

The pre-friction record gates the one-kernel logics against the decisions of commit 01d647c
(``golden.py``). Its learned runs were first recorded through torch, whose products differ in
their last bits between CPUs; with the portable controller they are the same everywhere. The
task must then run as it did before the friction circle: commit 08b80e9, whose decisions are
bit-identical to 01d647c's (its own golden test), run from a checkout of it::

    git worktree add /tmp/old 08b80e9
    python -m tests.leftturn.record_pre_friction /tmp/old

It checks that the old checkout reproduces the record's other runs bit for bit (so the task
there is the recorded one), then replaces only the learned runs.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from safeswitch.training.policies import load_policy
from tests.leftturn.golden import POLICIES, PRE_FRICTION, portable_parameters

LEARNED = {  # run -> (golden policy, the run's episode overrides, switching)
    "shipped_paper": ("paper_warm", {"episode": {"learned_scope": "episode"}}, "paper"),
    "shipped_certified": ("paper_warm", {"episode": {"learned_scope": "episode"}}, "certified"),
    "scratch_window_paper": ("paper_scratch", None, "paper"),
}
#: A run whose driver never changed: the old checkout must reproduce it bit for bit.
WITNESS = "rule_paper"

# Runs in the old checkout's interpreter: its safeswitch and its golden digest, numpy, and
# portable.py loaded by path.
_OLD = r"""
import importlib.metadata, importlib.util, sys, tomllib
import numpy as np
from safeswitch.core import registry

# the old checkout's logics by its own entry points (the installed ones are today's)
with open(sys.argv[4] + "/pyproject.toml", "rb") as f:
    group = tomllib.load(f)["project"]["entry-points"][registry.ENTRY_POINT_GROUP]
registry._entry_points = {
    name: importlib.metadata.EntryPoint(name, value, registry.ENTRY_POINT_GROUP)
    for name, value in group.items()
}
from safeswitch.leftturn.config import resolve_config
from tests.leftturn.golden import digest  # the old checkout's

spec = importlib.util.spec_from_file_location("portable", sys.argv[1])
portable = importlib.util.module_from_spec(spec); spec.loader.exec_module(portable)
params, out = np.load(sys.argv[2]), sys.argv[3]
RUNS = %(runs)r

def driver(prefix):
    act = portable.portable_driver(
        {k[len(prefix):]: params[k] for k in params.files if k.startswith(prefix)}
    )
    return lambda: (lambda obs, state=None, tick=0: act(obs, state, tick))

data = {%(witness)r: digest(resolve_config({"episode": {"learned_scope": "never"}}),
                            lambda: lambda obs, state=None, tick=0: np.zeros(len(obs)))}
for name, (policy, overrides, switching) in RUNS.items():
    data[name] = digest(resolve_config(overrides, switching=switching), driver(policy + "/"))
np.savez(out, **data)
"""


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not (Path(argv[0]) / "src" / "safeswitch").is_dir():
        print(__doc__)
        return 2
    old = Path(argv[0]).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        params = {}
        for name in {policy for policy, _, _ in LEARNED.values()}:
            for key, value in portable_parameters(load_policy(POLICIES / name)).items():
                params[f"{name}/{key}"] = value
        np.savez(Path(tmp) / "params.npz", **params)
        script = _OLD % {"runs": LEARNED, "witness": WITNESS}
        env = {**os.environ, "PYTHONPATH": f"{old / 'src'}{os.pathsep}{old}"}
        subprocess.run(
            [sys.executable, "-c", script, str(Path(__file__).with_name("portable.py")),
             str(Path(tmp) / "params.npz"), str(Path(tmp) / "out.npz"), str(old)],
            check=True, env=env, cwd=tmp,
        )  # fmt: skip
        fresh = dict(np.load(Path(tmp) / "out.npz"))
    recorded = dict(np.load(PRE_FRICTION))
    if not np.array_equal(fresh.pop(WITNESS), recorded[WITNESS]):
        print(f"{old} does not reproduce the record's {WITNESS} run: not the recorded task")
        return 1
    recorded.update(fresh)
    partial = PRE_FRICTION.with_suffix(".partial.npz")
    np.savez_compressed(partial, **recorded)
    partial.replace(PRE_FRICTION)
    print(f"wrote {PRE_FRICTION} (learned runs: {', '.join(fresh)})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
