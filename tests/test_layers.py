"""The package's layers: each imports only the layers below it (no cycles between packages),
and only ``report`` imports matplotlib.

core → sim → leftturn → sumo, evaluation → training, report → app, examples → cli
(``io`` and ``progress`` are leaf utilities every layer may use.)
"""

import ast
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
    "report": UTILITIES | {"core", "sim", "leftturn", "evaluation"},
    "examples": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training"},
    "bench": UTILITIES | {"core", "sim", "leftturn", "evaluation", "training"},
}
BELOW["app"] = BELOW["training"] | {"training", "report", "examples", "sumo"}
BELOW["cli"] = BELOW["app"] | {"app", "bench"}


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
