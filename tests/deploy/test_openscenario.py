"""OpenSCENARIO out and in (issue #42): every file is valid against the ASAM schema, parses back
to the very scenario it was written from, and evaluates to the same outcomes — random scenarios
and falsified counterexamples alike."""

import csv
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import xmlschema

from safeswitch.app.evaluate import evaluate
from safeswitch.app.export_scenario import export_scenarios
from safeswitch.cli import main
from safeswitch.deploy.openscenario import (
    OpenScenarioError,
    read_scenarios,
    record,
    schema_file,
)
from safeswitch.evaluation.evaluate import baseline_setup
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask

FIELDS = ("ego_start_distance", "ego_speed", "north_speed", "arrival_offset")


def episodes(folder):
    with open(folder / "episodes.csv", newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(scope="module")
def random50(tmp_path_factory):
    folder = tmp_path_factory.mktemp("xosc") / "random"
    index = export_scenarios(folder, "random", 50, seed=11)
    return folder, index


def test_every_file_is_valid_against_the_asam_schema(random50):
    folder, index = random50
    schema = xmlschema.XMLSchema(str(schema_file()))
    files = sorted(folder.glob("*.xosc"))
    assert len(files) == len(index["scenarios"]) == 50
    for file in files[:10]:
        schema.validate(str(file))  # raises on the first schema error
        root = ET.parse(file).getroot()
        assert root.find("FileHeader").get("revMinor") == "0"
        assert root.find("RoadNetwork/LogicFile").get("filepath") == "intersection.xodr"
    assert (folder / "intersection.xodr").stat().st_size > 10_000


@pytest.mark.slow
def test_the_files_parse_back_to_the_very_scenarios_written(random50):
    folder, _ = random50
    config, _ = baseline_setup("rule", None)
    task = LeftTurnTask(config)
    read, names = read_scenarios(folder, task)
    drawn = task.scenario_set(11, 50)
    order = [int(n.split("-")[1]) for n in names]
    for field in FIELDS:  # every digit
        assert np.array_equal(getattr(read, field), getattr(drawn, field)[order]), field


def test_export_parse_evaluate_gives_the_same_outcomes(random50, tmp_path):
    folder, index = random50
    direct = evaluate("rule", None, "random", 50, 11, None, tmp_path / "direct")
    replay = evaluate("rule", None, f"openscenario:{folder}", 0, 0, None, tmp_path / "replay")
    for key in direct:
        if key not in ("scenarios", "seed"):
            assert replay[key] == direct[key], key
    by_name = {row["episode"]: row for row in episodes(tmp_path / "direct")}
    rows = episodes(tmp_path / "replay")
    assert len(rows) == 50
    for row in rows:
        assert row == by_name[row["episode"]]
    recorded = {e["file"][:-5]: e for e in index["scenarios"]}
    for row in rows:
        assert (row["collision"] == "True") == recorded[row["episode"]]["collision"]


def test_the_oncoming_cars_trajectory_is_the_recorded_path(random50):
    folder, _ = random50
    config, policy = baseline_setup("rule", None)
    task = LeftTurnTask(config)
    file = folder / "random-3.xosc"
    scenario, _ = read_scenarios(file, task)
    runs, _ = record(task, scenario, policy)
    north = runs[0].north
    root = ET.parse(file).getroot()
    vertices = root.findall(".//Trajectory[@name='NorthTrajectory']//Vertex")
    t = np.array([float(v.get("time")) for v in vertices])
    xy = np.array([[float(v.find(".//WorldPosition").get(k)) for k in "xy"] for v in vertices])
    assert t[0] == 0.0 and t[-1] == pytest.approx(north.time[-1])
    # Linear interpolation between the vertices stays on the tick-by-tick path.
    x = np.interp(north.time, t, xy[:, 0])
    y = np.interp(north.time, t, xy[:, 1])
    assert np.max(np.hypot(x - north.x, y - north.y)) < 1e-3


def test_a_file_for_another_scene_or_edited_by_hand_is_refused(random50, tmp_path):
    folder, _ = random50
    config, _ = baseline_setup("rule", None)
    task = LeftTurnTask(config)
    text = (folder / "random-0.xosc").read_text()
    start = (
        ET.parse(folder / "random-0.xosc")
        .getroot()
        .find("ParameterDeclarations/ParameterDeclaration[@name='EgoStartDistance']")
        .get("value")
    )
    edited = tmp_path / "edited.xosc"
    edited.write_text(text.replace(f'value="{start}"', f'value="{float(start) + 2.0!r}"'))
    with pytest.raises(OpenScenarioError, match="Ego starts at"):
        read_scenarios(edited, task)
    garbled = tmp_path / "garbled.xosc"
    garbled.write_text(text.replace(f'value="{start}"', 'value="far"'))
    with pytest.raises(OpenScenarioError, match=r"EgoStartDistance .* is 'far'"):
        read_scenarios(garbled, task)
    invalid = tmp_path / "invalid.xosc"
    invalid.write_text(text.replace("<Storyboard>", "<Storyboard><Bogus/>"))
    with pytest.raises(OpenScenarioError, match=r"not valid OpenSCENARIO 1\.0"):
        read_scenarios(invalid, task)


@pytest.mark.slow
def test_every_falsified_counterexample_replays_its_failure(tmp_path, capsys):
    falsified = tmp_path / "falsified"
    args = ["falsify", "--controller", "rule", "--budget", "1000", "--generation", "500",
            "--workers", "0", "--out", str(falsified), "--no-progress"]  # fmt: skip
    assert main(args) == 0
    with open(falsified / "scenarios.csv", newline="") as handle:
        failed = [r for r in csv.DictReader(handle) if r["collision"] == "1"]
    assert failed, "the paper logic's rule failed nowhere: the search found no counterexample"
    out = tmp_path / "counterexamples"
    assert main(["export-scenario", "--scenarios", f"falsify:{falsified}", "--out", str(out),
                 "--no-progress"]) == 0  # fmt: skip
    assert f"{len(failed):,} of them end in a collision" in capsys.readouterr().out
    summary = evaluate("rule", None, f"openscenario:{out}", 0, 0, None, tmp_path / "replay")
    assert summary["episodes"] == summary["collisions"] == len(failed)
    rows = sorted(episodes(tmp_path / "replay"), key=lambda r: r["episode"])
    assert sorted(float(r["ego_start_distance_m"]) for r in rows) == pytest.approx(
        sorted(float(r["ego_start_distance_m"]) for r in failed), abs=1e-3
    )


def test_the_command_line_checks_what_does_not_apply(random50, capsys):
    folder, _ = random50
    code = main(["evaluate", "--controller", "rule", "--scenarios", f"openscenario:{folder}",
                 "--episodes", "5"])  # fmt: skip
    assert code == 2 and "--episodes does not apply" in capsys.readouterr().err
    code = main(["evaluate", "--controller", "rule", "--scenarios", "openscenario:"])
    assert code == 2 and "openscenario:PATH" in capsys.readouterr().err
    code = main(["evaluate", "--controller", "rule", "--scenarios", "openscenario:/no/such"])
    assert code == 2 and "no such scenario file or folder" in capsys.readouterr().err


@pytest.mark.slow
def test_1000_random_scenarios_round_trip_to_identical_outcomes(tmp_path):
    export_scenarios(tmp_path / "xosc", "random", 1000, seed=1_000_003)
    direct = evaluate("rule", None, "random", 1000, 1_000_003, None, tmp_path / "direct")
    replay = evaluate("rule", None, f"openscenario:{tmp_path / 'xosc'}", 0, 0, None,
                      tmp_path / "replay")  # fmt: skip
    by_name = {row["episode"]: row for row in episodes(tmp_path / "direct")}
    rows = episodes(tmp_path / "replay")
    assert len(rows) == 1000 and all(row == by_name[row["episode"]] for row in rows)
    assert {k: v for k, v in replay.items() if k not in ("scenarios", "seed")} == {
        k: v for k, v in direct.items() if k not in ("scenarios", "seed")
    }


def test_scenarios_type_is_what_the_reader_builds():
    assert [f for f in Scenarios.__dataclass_fields__] == list(FIELDS)


def test_index_lists_parameters_and_outcomes(random50):
    _, index = random50
    entry = index["scenarios"][0]
    assert set(entry) >= {"file", "EgoStartDistance", "EgoSpeed", "NorthSpeed", "ArrivalOffset",
                          "collision", "outcome", "safety_steps", "min_separation_m"}  # fmt: skip
    assert index["source"]["controller"] == "rule" and index["openscenario"] == "1.0"
    assert json.loads(json.dumps(index)) == index


@pytest.mark.slow
def test_a_traffic_scene_exports_every_vehicle_from_entry_to_exit(tmp_path):
    out = tmp_path / "traffic"
    index = export_scenarios(out, "random", 3, seed=5, traffic="medium")
    schema = xmlschema.XMLSchema(str(schema_file()))
    for entry in index["scenarios"]:
        file = out / entry["file"]
        schema.validate(str(file))
        root = ET.parse(file).getroot()
        cars = [o.get("name") for o in root.iterfind("Entities/ScenarioObject")]
        assert cars[:2] == ["Ego", "North"] and len(cars) == 2 + entry["other_vehicles"] > 4
        for car in cars[2:]:
            # each enters where its trajectory starts, at the time its trajectory starts
            added = root.find(f".//Event[@name='{car}Enter']")
            first = root.find(f".//Trajectory[@name='{car}Trajectory']//Vertex")
            where = added.find(".//AddEntityAction//WorldPosition")
            assert where.get("x") == first.find(".//WorldPosition").get("x")
            rule = added.find(".//SimulationTimeCondition")
            assert float(rule.get("value")) == pytest.approx(
                max(float(first.get("time")) - 0.01, 0.0)
            )
        with pytest.raises(OpenScenarioError, match="holds a scene with traffic"):
            read_scenarios(file, LeftTurnTask(baseline_setup("rule", None)[0]))
