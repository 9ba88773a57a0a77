"""``safeswitch reproduce --quick``: the report holds every figure, animation and table it lists."""

import csv
import json
import re

import pytest
from PIL import Image

from safeswitch.app.reproduce import ENTRIES, TABLE, _figure_list
from safeswitch.cli import main
from safeswitch.leftturn.config import SCENARIO_NAMES

EPISODES = 24


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["reproduce", "--quick", "--out", str(out), "--episodes", str(EPISODES)]) == 0
    return out


def test_the_report_embeds_every_figure_and_animation_it_lists(report):
    summary = json.loads((report / "summary.json").read_text())
    page = (report / "report.html").read_text()
    listed = _figure_list(summary)
    assert len(listed) == 1 + 3 * (len(ENTRIES) - 1)  # comparison + 3 scenarios per controller
    pngs = re.findall(r'src="data:image/png;base64,', page)
    gifs = re.findall(r'src="data:image/gif;base64,', page)
    assert len(pngs) == len(listed)
    assert len(gifs) == len(SCENARIO_NAMES)
    assert not re.search(r"(src|href)=\"(?!data:)", page)  # self-contained, offline
    markdown = (report / "report.md").read_text()
    for stem, _ in listed:
        assert f"figures/{stem}.png" in markdown
        with Image.open(report / "figures" / f"{stem}.png") as image:
            assert image.size[0] > 400
    for scenario in SCENARIO_NAMES:
        with Image.open(report / "figures" / f"ppo-paper_{scenario}.gif") as gif:
            assert gif.n_frames >= 50  # an animation of the whole episode, not a still


def test_the_report_tables_name_every_controller_and_column(report):
    page = (report / "report.html").read_text()
    markdown = (report / "report.md").read_text()
    for entry in ENTRIES:
        assert f"<td>{entry.name}</td>" in page
        assert f"| {entry.name} |" in markdown
    for _, header, _ in TABLE:
        assert f"<th>{header}</th>" in page
    for scenario in SCENARIO_NAMES:
        assert f"<th>{scenario}</th>" in page
    assert page.count("reproduced:") == 4


def test_the_raw_results_hold_one_row_per_episode(report):
    summary = json.loads((report / "summary.json").read_text())
    assert set(summary["controllers"]) == {e.name for e in ENTRIES}
    for entry in ENTRIES:
        result = summary["controllers"][entry.name]
        assert result["random"]["episodes"] == EPISODES
        assert set(result["paper"]) == set(SCENARIO_NAMES)
        with open(report / "raw" / f"{entry.name}_random.csv") as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == EPISODES
        assert {"time_to_clear_s", "oracle_time_to_clear_s", "outcome"} <= set(rows[0])
    oracle = summary["controllers"]["oracle"]["random"]
    assert oracle["collisions"] == 0 and oracle["mean_efficiency"] == pytest.approx(1.0)
    # The safety net's effect on a reckless (full-throttle) learned controller.
    reckless = {r["switching"]: r for r in summary["reckless_full_throttle"]}
    assert reckless["none"]["collisions"] > 0
    assert reckless["certified"]["collisions"] == 0
