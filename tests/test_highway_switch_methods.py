"""``benchmarks/highway_switch.py``: which runs a command trains — a recipe's own runs with
``--imitation-only``, without the R_ADAS-alone ones, and the option refused without a weight."""

import pytest

pytest.importorskip("highway_env")


@pytest.fixture
def highway_switch(benchmark_module):
    return benchmark_module("highway_switch")


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
