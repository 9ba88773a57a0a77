"""``benchmarks/plants.py``: issue #39's table is computed from the benchmarks' results — the
traffic row's checks against what a results file records."""

import json

import pytest


@pytest.fixture
def plants(benchmark_module, monkeypatch, tmp_path):
    module = benchmark_module("plants")
    monkeypatch.setattr(module, "RESULTS", tmp_path)
    return module


def family(safety, efficiency=0.40, failures=0):
    return {
        "episodes": 1000,
        "failures": failures,
        "safety_activation_episodes": safety,
        "cleared_episodes": 200,
        "mean_efficiency": efficiency,
        "max_speed_kmh": 30.0,
    }


def write(tmp_path, runs, planners, config="traffic_certified"):
    (tmp_path / f"train_seeds_{config}.json").write_text(json.dumps({"runs": runs}))
    (tmp_path / "traffic_certified.json").write_text(json.dumps({"rows": planners}))


PLANNERS = [
    {"controller": "gap_planner", "traffic": "test", "cleared_episodes": 100,
     "mean_efficiency": 0.30},
    {"controller": "gap_planner (narrower zones)", "traffic": "test", "cleared_episodes": 230,
     "mean_efficiency": 0.38},
]  # fmt: skip


def run(seed, warm=None, **families):
    densities = {f: family(20) for f in ("test", "light", "medium", "heavy")}
    densities.update(families)
    return {"seed": seed, "warm_start_collisions": warm, "training_collision_episodes": 0,
            "traffic": densities}  # fmt: skip


def test_the_traffic_row_checks_every_density_and_the_planner_under_the_same_filter(
    plants, tmp_path
):
    write(tmp_path, [run(1), run(2), run(3)], PLANNERS)
    row = plants.traffic()
    checks = row["checks"]
    # the shipped recipe is PPO from a random start; the clone shipped beside it is not
    assert checks["from a random start (no demonstrations)"] is True and row["shipped"]
    assert "PPO with R_ADAS from a random start" in row["method"] and row["seeds"] == [1, 2, 3]
    write(tmp_path, [run(1, warm=0), run(2, warm=0)], PLANNERS, "traffic_certified_clone")
    clone = plants.traffic("traffic_certified_clone", shipped=False)
    assert clone["checks"]["from a random start (no demonstrations)"] is False
    assert "clone of the gap planner" in clone["method"] and not clone["shipped"]
    assert checks["0 collisions in training and on 1,000 `test` scenes"] is True
    assert checks["safety action ≤ 5 % of episodes at every density"] is True
    # the recipe's narrower zones: compared with the planner under them (0.38), not 0.30
    efficiency = [k for k in checks if k.startswith("efficiency")]
    assert efficiency == ["efficiency ≥ the gap planner's (0.380 on `test`, the same filter)"]
    assert checks[efficiency[0]] is True  # 0.40 ≥ 0.38


def test_one_density_over_the_budget_or_one_failure_misses_the_row(plants, tmp_path):
    write(tmp_path, [run(1), run(2, light=family(51)), run(3)], PLANNERS)
    assert plants.traffic()["checks"]["safety action ≤ 5 % of episodes at every density"] is False
    write(tmp_path, [run(1), run(2), run(3, test=family(20, failures=1))], PLANNERS)
    checks = plants.traffic()["checks"]
    assert checks["0 collisions in training and on 1,000 `test` scenes"] is False
    write(tmp_path, [run(1), run(2, test=family(20, efficiency=0.37)), run(3)], PLANNERS)
    checks = plants.traffic()["checks"]
    assert not checks["efficiency ≥ the gap planner's (0.380 on `test`, the same filter)"]


def test_no_results_no_row(plants):
    assert plants.traffic() is None


def test_the_shipped_table_has_one_row_per_plant_from_the_full_table(benchmark_module, capsys):
    """``--shipped`` (the README's table) keeps exactly one recipe per plant — the one its
    shipped policies or the pipeline's defaults come from — out of the full table's rows."""
    plants = benchmark_module("plants")
    plants.main(["--json"])
    every = json.loads(capsys.readouterr().out)
    plants.main(["--json", "--shipped"])
    shipped = json.loads(capsys.readouterr().out)
    names = [row["plant"] for row in shipped]
    assert len(names) == len(set(names)) == len({row["plant"] for row in every})
    assert all(row in every for row in shipped) and len(shipped) < len(every)
    highway = next(row for row in shipped if row["plant"] == "highway-env")
    assert "as shipped" in highway["method"]


def left_turn_run(seed, cleared=982, efficiency=0.851):
    return {"seed": seed, "training_collision_episodes": 0, "collisions": 0,
            "speeding_episodes": 0, "mean_efficiency": efficiency, "cleared_episodes": cleared,
            "safety_activation_episodes": 4, "comfort_violation_fraction": 0.0,
            "max_speed_kmh": 30.0, "cut_episodes": 288}  # fmt: skip


def test_a_left_turn_variant_is_checked_against_its_logics_row_and_is_not_shipped(plants, tmp_path):
    name, logic, _, before = plants.LEFT_TURN_VARIANTS[0]
    results = tmp_path / f"train_seeds_{name.replace('/', '_')}.json"
    runs = [left_turn_run(1), left_turn_run(2, efficiency=0.847), left_turn_run(3, cleared=990)]
    results.write_text(json.dumps({"runs": runs}))
    (row,) = plants.variants()
    assert row["plant"] == f"left turn, `{logic}`" and row["shipped"] is False
    assert row["source"].startswith(before) and f"--config {name}" in row["source"]
    assert "go predictor" in row["method"]
    # the `certified` row's targets: 99 % cleared and 0.85 on every seed
    assert row["checks"]["efficiency ≥ 0.85"] is False  # seed 2: 0.847
    assert row["checks"]["clears ≥ 99 %"] is False  # seeds 1 and 2: 982
    assert row["checks"]["never above 30 km/h"] is True
    results.write_text(json.dumps({"runs": [left_turn_run(s, 990, 0.86) for s in (1, 2, 3)]}))
    assert all(plants.variants()[0]["checks"].values())
