"""The package's layers: each imports only the layers below it (no cycles between packages),
and only ``report`` imports matplotlib.

core → sim → leftturn → sumo, evaluation, runtime → training → report, deploy → app, examples
→ logics, cli (``io`` and ``progress`` are leaf utilities every layer may use). ``runtime``
(the exported controller) sits on the simulation layers alone: it runs without the training
stack.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "src" / "safeswitch"

UTILITIES = {"io", "progress"}
BELOW = {
    "io": set(),
    "progress": set(),
    "core": UTILITIES,
    "sim": UTILITIES | {"core"},
    "leftturn": UTILITIES | {"core", "sim"},
    "sumo": UTILITIES | {"core", "sim", "leftturn"},
    "evaluation": UTILITIES | {"core", "sim", "leftturn"},
    "training": UTILITIES | {"core", "sim", "leftturn", "evaluation"},
    "report": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training"},
    "examples": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training"},
    "bench": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training"},
    "runtime": UTILITIES | {"core", "sim", "leftturn"},
    "deploy": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training", "runtime"},
}
# the built-in logics that serve several plants under one name (``certified``)
BELOW["logics"] = BELOW["examples"] | {"examples"}
BELOW["app"] = BELOW["training"] | {"training", "report", "examples", "sumo", "deploy", "runtime"}
BELOW["cli"] = BELOW["app"] | {"app", "bench", "deploy"}


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts == ("__init__",) or parts[0] in ("__main__",):
            continue
        yield parts[0], path


def imported(path):
    """Every module name ``path`` imports, at module level or inside functions."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module


@pytest.mark.parametrize(("layer", "path"), list(modules()), ids=lambda v: str(v))
def test_each_module_imports_only_the_layers_below_it(layer, path):
    assert layer in BELOW, f"{path} is in a package no layer rule covers"
    for name in imported(path):
        if not name.startswith("safeswitch."):
            assert not name.startswith("matplotlib") or layer == "report", (
                f"{path} imports matplotlib; only safeswitch.report may"
            )
            continue
        target = name.split(".")[1]
        assert target == layer or target in BELOW[layer], (
            f"{path.relative_to(PACKAGE)} ({layer}) imports {name} ({target}), which is not "
            f"below it"
        )


# -- within a package ------------------------------------------------------------------------

#: The left-turn package bottom-up: each module imports only modules listed before it (at
#: module level or inside a function). The scene hooks the logics read are typed protocols in
#: ``views``; the logics are built from a finished scene; only ``make`` knows every scene.
LEFTTURN_ORDER = (
    "config", "go_model", "rewards", "scenarios", "views", "perception", "logics.certified",
    "logics.paper", "task", "traffic", "make", "statistics", "info", "spaces", "render", "env",
    "vec_env",
)  # fmt: skip


def module_name(path):
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(("safeswitch", *(parts[:-1] if parts[-1] == "__init__" else parts)))


def test_the_leftturn_modules_import_only_the_ones_below_them():
    package = PACKAGE / "leftturn"
    listed = {f"safeswitch.leftturn.{m}" for m in LEFTTURN_ORDER}
    found = {module_name(p) for p in package.rglob("*.py") if p.name != "__init__.py"}
    assert found == listed, f"modules not in LEFTTURN_ORDER: {sorted(found ^ listed)}"
    rank = {f"safeswitch.leftturn.{m}": i for i, m in enumerate(LEFTTURN_ORDER)}
    for path in package.rglob("*.py"):
        if path.name == "__init__.py":
            continue  # the package's lazy exports
        me = module_name(path)
        for name in imported(path):
            target = next((m for m in rank if name == m or name.startswith(m + ".")), None)
            assert target is None or rank[target] < rank[me], (
                f"{me} imports {name}, which is not below it in LEFTTURN_ORDER"
            )


def test_no_package_has_an_import_cycle_among_its_modules():
    """Function-level imports count: a cycle hidden inside a function is still a cycle."""
    graph = {}
    for path in PACKAGE.rglob("*.py"):
        if path.name == "__init__.py":
            continue
        me = module_name(path)
        graph[me] = {
            name for name in imported(path)
            if name.startswith("safeswitch.") and name != me
        }  # fmt: skip
    modules_ = set(graph)
    for me in graph:
        graph[me] = {m for m in modules_ if any(n == m or n.startswith(m + ".") for n in graph[me])}
        graph[me].discard(me)
    state = {}

    def visit(node, trail):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycle = [*trail[trail.index(nxt) :], nxt]
                raise AssertionError("import cycle: " + " → ".join(cycle))
            if nxt not in state:
                visit(nxt, [*trail, nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


def test_the_configuration_imports_no_simulation_logic_planner_or_learner():
    """Reading a training configuration needs the configuration classes, not the code they
    configure: of the package it loads the configuration modules, the parameter classes and
    the logic registry alone (no simulation, task, logic or planner), and neither networkx,
    torch nor SB3."""
    import subprocess
    import sys

    allowed = {
        "safeswitch", "safeswitch.core", "safeswitch.core.config", "safeswitch.core.pid_gains",
        "safeswitch.core.registry", "safeswitch.core.switching", "safeswitch.core.arrays",
        "safeswitch.sim", "safeswitch.sim.params", "safeswitch.leftturn",
        "safeswitch.leftturn.config", "safeswitch.evaluation",
        "safeswitch.evaluation.planner_config", "safeswitch.training",
        "safeswitch.training.config",
    }  # fmt: skip
    code = (
        "import sys, safeswitch.training.config\n"
        "print(' '.join(m for m in sys.modules if m.split('.')[0] in "
        "('safeswitch', 'networkx', 'torch', 'stable_baselines3')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = set(done.stdout.split())
    assert "safeswitch.training.config" in loaded  # the probe saw the import
    assert loaded <= allowed, f"configuration loads {sorted(loaded - allowed)}"


_REGISTRATION = """
import sys
first = sys.argv[1]
if first == "gymnasium":
    import gymnasium
import safeswitch
assert ("gymnasium" in sys.modules) == (first == "gymnasium"), "import safeswitch loaded Gymnasium"
import gymnasium as gym
for env_id in (safeswitch.ENV_ID, safeswitch.TRAFFIC_ENV_ID):
    assert env_id in gym.registry, env_id
env = gym.make(safeswitch.ENV_ID)
print(env.reset(seed=0)[0].shape)
"""


@pytest.mark.parametrize("first", ["safeswitch", "gymnasium"])
def test_the_package_registers_its_ids_without_importing_gymnasium_itself(first):
    done = subprocess.run(
        [sys.executable, "-c", _REGISTRATION, first], capture_output=True, text=True,
        timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "(6,)"
