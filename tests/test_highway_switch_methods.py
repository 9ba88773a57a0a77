"""``benchmarks/highway_switch.py``: which runs a command trains — a recipe's own runs with
``--imitation-only``, without the R_ADAS-alone ones, and the option refused without a weight."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"

pytest.importorskip("highway_env")


@pytest.fixture
def highway_switch(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(
        "highway_switch_under_test", BENCHMARKS / "highway_switch.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("highway_switch_under_test", None)


def test_the_recipe_runs_replace_the_first_logics_r_adas_alone_runs(highway_switch):
    methods = highway_switch.methods
    assert methods(["certified", "none"]) == [("certified", 0.0), ("none", 0.0)]
    assert methods(["certified", "none"], 1.0) == [
        ("certified", 0.0), ("none", 0.0), ("certified", 1.0)
    ]  # fmt: skip
    assert methods(["certified", "none"], 1.0, imitation_only=True) == [
        ("none", 0.0), ("certified", 1.0)
    ]  # fmt: skip


def test_imitation_only_without_a_weight_is_refused(highway_switch, capsys):
    with pytest.raises(SystemExit) as exit_:
        highway_switch.main(["--imitation-only", "--logics", "none"])
    assert exit_.value.code == 2
    assert "--imitation-only needs --imitation W" in capsys.readouterr().err
