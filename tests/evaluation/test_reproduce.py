"""``safeswitch reproduce --quick``: the report holds every figure, animation and table it
lists, and never hides a collision."""

import csv
import json
import re
from html.parser import HTMLParser

import pytest
from markupsafe import escape
from PIL import Image

from safeswitch.app.reproduce import ENTRIES, TRAFFIC_PRESETS
from safeswitch.cli import main
from safeswitch.evaluation.verdict import verdict
from safeswitch.leftturn.config import SCENARIO_NAMES
from safeswitch.report.document import COMPARISON, DEFINITIONS, VERDICT_POLICIES, figure_list
from safeswitch.training.shipped import MISSING_TARGETS

EPISODES = 24


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["reproduce", "--quick", "--out", str(out), "--episodes", str(EPISODES)]) == 0
    return out


class Tables(HTMLParser):
    """Every <table> of a page as rows of (cell texts, row class)."""

    def __init__(self):
        super().__init__()
        self.tables, self._row, self._cell, self._class = [], None, None, None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self._row, self._class = [], dict(attrs).get("class")
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._row.append(self._cell)
            self._cell = None
        elif tag == "tr":
            self.tables[-1].append((self._row, self._class))


def tables(page):
    parser = Tables()
    parser.feed(page)
    return parser.tables


#: The report's tables in page order: the verdict first.
VERDICT, COMPARED, SCENARIOS, POLICIES, STORY = range(5)


@pytest.mark.slow
def test_the_report_opens_with_a_verdict_that_matches_the_summary(report):
    """Every shipped policy's targets, ✔ or ✘ as :func:`verdict` says of its own summary, each
    missed target drawn red — before any other table."""
    summary = json.loads((report / "summary.json").read_text())
    page = (report / "report.html").read_text()
    assert page.index("<h2>Verdict</h2>") < page.index("<table")
    rows = tables(page)[VERDICT][1:]
    assert [row[0].split(" (")[0] for row, _ in rows] == list(VERDICT_POLICIES)
    missed = re.findall(
        r"<tr>(.*?)</tr>", page.split("<h2>Verdict</h2>", 1)[1].split("</table>", 1)[0], re.DOTALL
    )[1:]  # the body rows' html, to read the red cells
    for (row, _), html in zip(rows, missed, strict=True):
        checks = verdict(summary["controllers"][row[0].split(" (")[0]]["random"])
        assert [cell[0] for cell in row[1:]] == [c.mark for c in checks]
        assert html.count(" bad") == sum(c.ok is False for c in checks)
    # the shipped policies known to miss their targets on this plant say why, under the verdict
    verdict_part = page.split("<h2>Verdict</h2>", 1)[1].split("<h2>", 1)[0]
    for folder, name in (("paper", "ppo-paper"), ("certified", "ppo-certified")):
        if folder in MISSING_TARGETS:
            # as the template writes it (Jinja escapes the apostrophes)
            assert f"<li>{escape(f'{name}: {MISSING_TARGETS[folder]}')}</li>" in verdict_part


@pytest.mark.slow
def test_the_report_embeds_every_figure_and_animation_it_lists(report):
    summary = json.loads((report / "summary.json").read_text())
    page = (report / "report.html").read_text()
    listed = figure_list(summary)
    assert len(listed) == 3 * (len(ENTRIES) - 1)  # 3 scenarios per controller but the oracle
    pngs = re.findall(r'src="data:image/png;base64,', page)
    gifs = re.findall(r'src="data:image/gif;base64,', page)
    # the comparison, clearing in traffic, training curves, perception errors
    assert len(pngs) == len(listed) + 4
    assert len(gifs) == len(SCENARIO_NAMES) + 1  # and one in traffic
    assert "Traffic from every leg" in page and "SUMO as a second simulator" in page
    assert (
        "Training (the paper's Fig. 5)" in page
        and "figures/training_curves.png" in (report / "report.md").read_text()
    )
    assert not re.search(r"(src|href)=\"(?!data:)", page)  # self-contained, offline
    markdown = (report / "report.md").read_text()
    for stem, _ in listed:
        assert f"figures/{stem}.png" in markdown
        with Image.open(report / "figures" / f"{stem}.png") as image:
            assert image.size[0] > 400
    for scenario in SCENARIO_NAMES:
        with Image.open(report / "figures" / f"ppo-paper_{scenario}.gif") as gif:
            assert gif.n_frames >= 50  # an animation of the whole episode, not a still


@pytest.mark.slow
def test_the_report_defines_its_columns_and_says_how_each_policy_was_made(report):
    page = (report / "report.html").read_text()
    for name, _ in DEFINITIONS:
        assert f"<dt>{name}</dt>" in page
    assert "3 m/s²" in page and "5 m/s²" in page  # the comfort limits, with their values
    policies = tables(page)[POLICIES]
    made = {row[0]: row[1] for row, _ in policies[1:]}
    evaluated_under = {row[0]: row[2] for row, _ in policies[1:]}
    assert evaluated_under["ppo-paper"] == "paper"  # trained under guarded, run under paper
    assert made["ppo-paper"].startswith("PPO from a random initialisation")
    assert "trained under guarded, deployed under paper" in made["ppo-paper"]
    assert "speed limiter at 29.9 km/h" in made["ppo-certified"]
    assert "speed limiter at 29.9 km/h" in made["ppo-paper"]  # retrained with one (issue #39)
    assert "speed limiter at 29.9 km/h" in made["ppo-paper-warm"]  # retrained with one too
    assert "speed limiter" not in made["ppo-paper-scratch"]  # Table II as written: without
    # the paper policy's training guard assumed its scene; the certified policy's did not
    assert "training filter assumed other vehicles at most 0.05 m/s²" in made["ppo-paper"]
    assert "training filter assumed" not in made["ppo-certified"]
    assert made["ppo-paper-warm"].startswith("warm start (behaviour cloning of the planner")
    assert made["ppo-paper-scratch"].startswith("PPO from a random initialisation, 1,200,")
    # the policies trained in traffic, after the comparison's controllers
    assert made["ppo-traffic-certified"].startswith("in traffic from every leg: PPO from a random")
    assert "behaviour cloning of the gap planner" in made["clone-traffic-certified"]
    story = tables(page)[STORY]  # the training curves beside what the paper says of its own
    assert story[0][0] == ["the paper (Section V-B)", "this run"] and len(story) == 6
    comparison_header = tables(page)[COMPARED][0][0]
    for _, header, _ in COMPARISON:
        assert header in comparison_header
    assert page.count("reproduced:") == 4


@pytest.mark.slow
def test_a_collision_is_shown_in_every_table_and_figure_caption(report):
    """The unshielded policy collides in yield1 and yield2 (raw CSV); the report must say so
    wherever those episodes appear, and say "never cleared" rather than a number."""
    with open(report / "raw" / "ppo-unshielded_paper.csv") as handle:
        raw = {row["episode"]: row for row in csv.DictReader(handle)}
    crashed = [name for name, row in raw.items() if row["collision"] == "1"]
    assert crashed  # the premise: this policy collides in some paper scenario
    page = (report / "report.html").read_text()
    comparison, scenarios = tables(page)[COMPARED], tables(page)[SCENARIOS]
    header = comparison[0][0]
    summary = json.loads((report / "summary.json").read_text())
    for row, css in comparison[1:]:
        collisions = int(row[header.index("collisions")])
        assert collisions == summary["controllers"][row[0]]["random"]["collisions"]
        assert (css == "alert") == (collisions > 0)
    lines = {(row[0], row[1]): (row, css) for row, css in scenarios[1:]}
    for name in crashed:
        row, css = lines["ppo-unshielded", name]
        assert row[3].startswith("COLLISION at") and css == "alert"
        assert row[4] == "never cleared"  # not "nan s" — it never left the zone
        caption = dict(figure_list(summary))[f"ppo-unshielded_{name}"]
        assert "COLLISION at" in caption and caption in page
    text = re.sub(r'src="data:[^"]*"', "", page)
    assert not re.search(r"\bnan\b", text, re.IGNORECASE)
    assert not re.search(r"\bnan\b", (report / "report.md").read_text(), re.IGNORECASE)


@pytest.mark.slow
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
    assert reckless["paper"]["lost_control_episodes"] > 0  # the paper's rule knows no curves
    assert reckless["certified"]["failures"] == 0
    # In traffic: the policies trained there beside the paper policy, each under its logic;
    # under the certified filter none collides at any density.
    traffic = {(r["preset"], r["controller"], r["switching"]): r
               for r in summary["traffic"]["rows"]}  # fmt: skip
    for preset in TRAFFIC_PRESETS:
        assert (preset, "ppo-traffic-paper", "paper") in traffic
        assert traffic[preset, "ppo-traffic-certified", "certified"]["collisions"] == 0


@pytest.mark.slow
def test_the_report_measures_perception_errors(report):
    """Every controller at every level, random and adversarial; the certified logic told the
    bounds never fails, and the page shows the table and the figure."""
    summary = json.loads((report / "summary.json").read_text())
    rows = summary["perception"]["rows"]
    assert {(r["level"], r["errors"]) for r in rows} == {
        (x, e) for x in (0.0, 1.0, 2.0, 3.0) for e in ("random", "adversarial")
    }
    declared = [r for r in rows if r["controller"].endswith("declared bounds")]
    assert len(declared) == 8 and all(r["failures"] == 0 for r in declared)
    assert all(r["episodes"] == summary["perception"]["episodes"] for r in rows)
    page = (report / "report.html").read_text()
    assert "Perception (the paper's Remark 2)" in page
    assert 'alt="failures and efficiency against the perception error level"' in page
    assert (report / "figures" / "perception.png").stat().st_size > 10_000


@pytest.mark.slow
def test_reproduce_refuses_to_overwrite_a_report_without_overwrite(report, capsys):
    args = ["reproduce", "--quick", "--out", str(report), "--episodes", "2"]
    assert main(args) == 2
    assert "is not empty" in capsys.readouterr().err


def test_make_demo_runs_the_demo_command_which_replaces_its_own_report():
    """`make demo` twice must work: the Makefile calls `safeswitch demo`, which is
    `reproduce --quick` into out/demo with --overwrite on (a second run replaces the files the
    first one wrote instead of refusing)."""
    from pathlib import Path

    from safeswitch.cli import build_parser

    makefile = (Path(__file__).resolve().parents[2] / "Makefile").read_text(encoding="utf-8")
    recipe = makefile.split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    assert "safeswitch demo" in recipe and "reproduce" not in recipe
    args = build_parser().parse_args(["demo"])
    assert (args.out, args.quick, args.overwrite, args.episodes) == ("out/demo", True, True, 1000)
    assert args.func.__name__ == "_reproduce"
