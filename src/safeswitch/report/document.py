"""The reproduction report as Markdown and as one self-contained HTML page, from the same
tables and the same Jinja2 templates (``report/templates``).

Every table shows collisions; an episode that never left its conflict zone reads "never
cleared", not a number.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jinja2

from safeswitch.evaluation.verdict import COMFORT_BUDGET, verdict
from safeswitch.leftturn.config import SCENARIO_NAMES
from safeswitch.training.shipped import MISSING_TARGETS, SHIPPED_DIR

TEMPLATES = Path(__file__).resolve().parent / "templates"

#: Columns of the comparison table: (summary key, header, format). Every count that could hide
#: a violation stands beside the efficiency.
COMPARISON = (
    ("failures", "failures", "{:d}"),
    ("collisions", "collisions", "{:d}"),
    ("lost_control_episodes", "lost control", "{:d}"),
    ("safety_activation_episodes", "safety episodes", "{:d}"),
    ("comfort_violation_fraction", "comfort exceeded (ticks)", "{:.2%}"),
    ("comfort_violation_episodes", "comfort exceeded (episodes)", "{:d}"),
    ("speeding_episodes", "speeding", "{:d}"),
    ("max_speed_kmh", "top speed [km/h]", "{:.1f}"),
    ("stops", "full stops", "{:d}"),
    ("cut_episodes", "cut", "{:d}"),
    ("yield_episodes", "yield", "{:d}"),
    ("never_cleared_episodes", "never cleared", "{:d}"),
    ("mean_time_to_clear_s", "time to clear [s]", "{:.2f}"),
    ("faster_than_oracle_episodes", "faster than the oracle", "{:d}"),
    ("mean_efficiency", "efficiency", "{:.3f}"),
    ("ttc_conflict_episodes", "TTC ≤ 1.5 s", "{:d}"),
    ("mean_min_pet_s", "min PET [s]", "{:.2f}"),
    ("mean_return", "return", "{:.0f}"),
)

#: Columns of the traffic table.
TRAFFIC = (
    ("failures", "failures", "{:d}"),
    ("collisions", "collisions", "{:d}"),
    ("safety_activation_episodes", "safety episodes", "{:d}"),
    ("comfort_violation_fraction", "comfort exceeded (ticks)", "{:.2%}"),
    ("comfort_violation_episodes", "comfort exceeded (episodes)", "{:d}"),
    ("speeding_episodes", "speeding", "{:d}"),
    ("max_speed_kmh", "top speed [km/h]", "{:.1f}"),
    ("cleared_episodes", "cleared", "{:d}"),
    ("mean_time_to_clear_s", "time to clear [s]", "{:.2f}"),
    ("faster_than_oracle_episodes", "faster than the oracle", "{:d}"),
    ("mean_efficiency", "efficiency", "{:.3f}"),
    ("ttc_conflict_episodes", "TTC ≤ 1.5 s", "{:d}"),
    ("mean_min_pet_s", "min PET [s]", "{:.2f}"),
)

#: Counts that break a target unless they are 0: their cells are drawn red (as a collision's).
MUST_BE_ZERO = frozenset(
    {"failures", "collisions", "lost_control_episodes", "speeding_episodes",
     "sumo_collision_episodes"}
)  # fmt: skip

#: The shipped policies the verdict judges against the targets (the results the project
#: claims; the others are baselines and ablations).
VERDICT_POLICIES = ("ppo-paper", "ppo-certified")

#: What each column means (the report's introduction lists them).
DEFINITIONS = (
    ("failures", "collisions and losses of control: every episode that ended in one"),
    ("collisions", "episodes that ended with the two cars' footprints touching"),
    (
        "lost control",
        "episodes that ended with the ego more than half a lane off its route: its tyres slid "
        "(every vehicle keeps its combined acceleration within the friction circle μ·g)",
    ),
    (
        "safety episodes / safety ticks",
        "episodes (ticks) in which the Safety controller's action was executed instead of the "
        "proposal — the paper's s*",
    ),
    (
        "comfort exceeded (ticks / episodes)",
        "share of ticks with |a_lon| > {lon:g} m/s² or |a_lat| > {lat:g} m/s² (the paper's "
        "comfort limits) / episodes with at least one such tick",
    ),
    ("full stops", "episodes in which the ego's speed fell below 0.1 m/s"),
    (
        "speeding",
        "episodes in which the ego drove faster than {tolerated_kmh:.0f} km/h (the speed limit "
        "plus the 5 km/h at which R_v is still at its best; the oracle's speed limit), by "
        "more than 0.1 km/h",
    ),
    ("top speed", "the ego's highest speed in any episode"),
    (
        "cut / yield / never cleared",
        "episodes in which the ego left its conflict zone before the north car left its own / "
        "after it / not within the horizon (cut + yield = cleared)",
    ),
    (
        "faster than the oracle",
        "episodes that cleared more than 0.05 s sooner than the oracle, which keeps every limit "
        "on its point-mass model (two 20 ms ticks of reading and rounding are allowed): by "
        "breaking a limit, speeding or comfort (the cell is then red), or by what the model "
        "rules out and the rules allow — a line within the lane off the route's centre line, "
        "or sharing the conflict area with the north car",
    ),
    ("cleared", "episodes in which the ego left its conflict zone within the {horizon:g} s"),
    (
        "time to clear",
        "mean time until the ego left its conflict zone, over the cleared episodes ('never' "
        "when none cleared)",
    ),
    (
        "efficiency",
        "mean over scenarios of the oracle's time to clear divided by the controller's; an "
        "episode that never clears counts with the whole {horizon:g} s horizon; above 1 in a "
        "scenario, the controller did what the oracle's point-mass model rules out (speeding, "
        "breaking a comfort limit, sharing the conflict area with the north car, or taking "
        "the turn faster than a point mass may)",
    ),
    (
        "TTC ≤ 1.5 s",
        "episodes whose smallest time to collision at a conflict zone (both drivers keeping "
        "their speed; Hayward 1972, as in the FHWA's SSAM) was at most 1.5 s — SSAM's "
        "threshold for a traffic conflict",
    ),
    (
        "min PET",
        "smallest post-encroachment time (Allen et al. 1978: from one vehicle leaving the "
        "conflict zone to the other entering it), mean over the episodes with one",
    ),
    (
        "return",
        "mean episode return: Eq. 5 (R_ADAS + R_lka + R_v + R_a_lon + R_a_lat) summed over the "
        "{horizon:g} s episode",
    ),
)


@dataclass(frozen=True)
class Table:
    """A report table: its header, rows of cell texts, the rows that show a failure (drawn
    red), the columns holding words rather than numbers (aligned left) and, per row, the cells
    that show a violation (drawn red)."""

    header: list[str]
    rows: list[list[str]]
    alert: list[bool]
    text_columns: tuple[int, ...] = (0,)
    bad: list[list[bool]] | None = None

    def bad_cell(self, row: int, column: int) -> bool:
        return self.bad is not None and self.bad[row][column]


def _cell(value: Any, fmt: str, key: str) -> str:
    if value is None:
        return "never" if key == "mean_time_to_clear_s" else "–"
    return fmt.format(value)


def _columns(
    r: dict[str, Any], columns: tuple[tuple[str, str, str], ...], lead: int
) -> tuple[list[str], list[bool]]:
    """A summary's cells for ``columns``, and which show a violation (``lead`` text cells
    first, never flagged)."""
    cells = [_cell(r.get(k), f, k) for k, _, f in columns]
    bad = [False] * lead + [_breaks(k, r.get(k), r) for k, _, _ in columns]
    return cells, bad


def _breaks(key: str, value: Any, summary: dict[str, Any]) -> bool:
    """Whether a cell's value breaks a target: a count of :data:`MUST_BE_ZERO` above 0,
    comfort exceeded on more ticks than the targets allow, or episodes sooner than the oracle
    of which any broke a limit (speeding or comfort; a summary without that split: any)."""
    if key == "comfort_violation_fraction":
        return value is not None and value > COMFORT_BUDGET
    if key == "faster_than_oracle_episodes":
        return bool(summary.get("faster_than_oracle_either", value))
    return key in MUST_BE_ZERO and bool(value)


def comparison_table(summary: dict[str, Any]) -> Table:
    rows, alert, bad = [], [], []
    for name, result in summary["controllers"].items():
        cells, flags = _columns(result["random"], COMPARISON, 1)
        rows.append([name, *cells])
        alert.append(result["random"]["failures"] > 0)
        bad.append(flags)
    return Table(["controller", *(h for _, h, _ in COMPARISON)], rows, alert, bad=bad)


def verdict_table(summary: dict[str, Any]) -> Table:
    """For each shipped policy of :data:`VERDICT_POLICIES`, each target ✔ or ✘ with its
    measured value (:mod:`safeswitch.evaluation.verdict`), on the random scenarios."""
    header: list[str] = ["policy (evaluated under)"]
    rows, bad = [], []
    for name in VERDICT_POLICIES:
        result = summary["controllers"].get(name)
        if result is None:
            continue
        checks = verdict(result["random"])
        if len(header) == 1:
            header += [f"{c.name} ({c.target})" for c in checks]
        rows.append([f"{name} ({result['switching']})", *(f"{c.mark} {c.value}" for c in checks)])
        bad.append([False, *(c.ok is False for c in checks)])
    return Table(header, rows, [False] * len(rows), text_columns=tuple(range(len(header))),
                 bad=bad)  # fmt: skip


def verdict_notes(summary: dict[str, Any]) -> list[str]:
    """For each judged policy that is a shipped one known to miss its targets on today's plant
    (:data:`~safeswitch.training.shipped.MISSING_TARGETS`), why and what was measured
    against it, beside the verdict's ✘."""
    notes = []
    for name in VERDICT_POLICIES:
        model = (summary["controllers"].get(name) or {}).get("model")
        if model is None or Path(model).resolve().parent != SHIPPED_DIR:
            continue
        why = MISSING_TARGETS.get(Path(model).name)
        if why is not None:
            notes.append(f"{name}: {why}")
    return notes


def scenario_table(summary: dict[str, Any]) -> Table:
    header = ["controller", "scenario", "outcome", "collision", "time to clear",
              "oracle", "min speed", "safety ticks", "comfort ticks"]  # fmt: skip
    rows, alert = [], []
    for name, result in summary["controllers"].items():
        for scenario in SCENARIO_NAMES:
            s = result["paper"][scenario]
            crashed = s["collision"]
            clear = s["time_to_clear_s"]
            oracle = s["oracle_time_to_clear_s"]
            rows.append(
                [
                    name,
                    scenario,
                    s["outcome"],
                    f"COLLISION at {s['collision_time_s']:.2f} s" if crashed else "no",
                    "never cleared" if clear is None else f"{clear:.2f} s",
                    "–" if oracle is None else f"{oracle:.2f} s",
                    f"{s['min_speed_kmh']:.1f} km/h",
                    str(s["safety_steps"]),
                    str(s["comfort_violation_steps"]),
                ]
            )
            alert.append(bool(crashed))
    return Table(header, rows, alert, text_columns=(0, 1, 2, 3))


def policy_table(summary: dict[str, Any]) -> Table:
    """Every controller of the comparison, then the policies trained in traffic: how each was
    made, the logic it is evaluated under, R_ADAS and its collisions in training (red if
    any)."""
    header = ["controller", "how it was made", "switching (evaluated under)", "R_ADAS",
              "collisions in training"]  # fmt: skip
    traffic = summary["traffic"].get("policies", {})  # absent from reports made before it
    rows, alert = [], []
    for name, result in [*summary["controllers"].items(), *traffic.items()]:
        t = result.get("training")
        if t is None:
            rows.append([name, result["label"], result["switching"] or "–", "–", "–"])
            alert.append(False)
            continue
        rows.append(
            [name, t["method"], result["switching"], "on" if t["adas_penalty"] else "off",
             str(t["collisions"])]
        )  # fmt: skip
        alert.append(t["collisions"] > 0)
    return Table(header, rows, alert, text_columns=(0, 1, 2, 3))


def reckless_table(summary: dict[str, Any]) -> Table:
    """Full throttle under each logic: a loss of control is a failure as a collision is."""
    reckless = summary["reckless_full_throttle"]
    rows = [
        [r["switching"], str(r["failures"]), str(r["collisions"]),
         str(r["lost_control_episodes"]), str(r["safety_activation_episodes"])]
        for r in reckless
    ]  # fmt: skip
    alert = [r["failures"] > 0 for r in reckless]
    header = ["switching logic", "failures", "collisions", "lost control", "safety episodes"]
    return Table(header, rows, alert)


def summary_table(
    records: list[dict[str, Any]],
    columns: tuple[tuple[str, str, str], ...],
    lead: tuple[str, ...],
    lead_cells: Callable[[dict[str, Any]], list[str]],
) -> Table:
    """One row per summary: its ``lead`` text cells, then ``columns``; a row with a failure is
    red, and so is every cell that breaks a rule."""
    rows, alert, bad = [], [], []
    for r in records:
        cells, flags = _columns(r, columns, len(lead))
        rows.append([*lead_cells(r), *cells])
        alert.append(r["failures"] > 0)
        bad.append(flags)
    header = [*lead, *(h for _, h, _ in columns)]
    return Table(header, rows, alert, text_columns=tuple(range(len(lead))), bad=bad)


def traffic_table(summary: dict[str, Any]) -> Table:
    return summary_table(
        summary["traffic"]["rows"], TRAFFIC, ("traffic", "controller", "switching"),
        lambda r: [r["preset"], r["controller"], r["switching"] or "–"],
    )  # fmt: skip


#: Columns of the perception table.
PERCEPTION = (
    ("failures", "failures", "{:d}"),
    ("collisions", "collisions", "{:d}"),
    ("safety_activation_episodes", "safety episodes", "{:d}"),
    ("speeding_episodes", "speeding", "{:d}"),
    ("comfort_violation_fraction", "comfort exceeded (ticks)", "{:.2%}"),
    ("comfort_violation_episodes", "comfort exceeded (episodes)", "{:d}"),
    ("cleared_episodes", "cleared", "{:d}"),
    ("mean_efficiency", "efficiency", "{:.3f}"),
)


def perception_table(summary: dict[str, Any]) -> Table:
    """The perception study's rows: level, errors, controller, then :data:`PERCEPTION`."""
    return summary_table(
        summary.get("perception", {}).get("rows", []), PERCEPTION,
        ("level", "errors", "controller"),
        lambda r: [f"{r['level']:g}", r["errors"], r["controller"]],
    )  # fmt: skip


#: Columns of the cross-simulator table.
SIMULATORS = (
    ("failures", "failures", "{:d}"),
    ("collisions", "collisions", "{:d}"),
    ("safety_activation_episodes", "safety episodes", "{:d}"),
    ("speeding_episodes", "speeding", "{:d}"),
    ("cleared_episodes", "cleared", "{:d}"),
    ("mean_time_to_clear_s", "time to clear [s]", "{:.2f}"),
    ("comfort_violation_fraction", "comfort exceeded (ticks)", "{:.2%}"),
    ("comfort_violation_episodes", "comfort exceeded (episodes)", "{:d}"),
    ("mean_efficiency", "efficiency", "{:.3f}"),
    ("sumo_collision_episodes", "SUMO's collisions", "{:d}"),
    ("assumption_break_episodes", "assumptions broken", "{:d}"),
)


def sumo_table(summary: dict[str, Any]) -> Table:
    return summary_table(
        summary.get("sumo", {}).get("rows", []), SIMULATORS, ("scene", "controller", "simulator"),
        lambda r: [r.get("scene", "paper's scene"), r["controller"], r["sim"]],
    )  # fmt: skip


def figure_list(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """The report's episode figures in order, as (file stem, caption)."""
    out = []
    for name, result in summary["controllers"].items():
        if name == "oracle":
            continue
        for scenario in SCENARIO_NAMES:
            ending = result["paper"][scenario].get("figure", "")
            caption = f"{result['label']}, scenario {scenario}: {ending}"
            out.append((f"{name}_{scenario}", caption))
    return out


def _context(summary: dict[str, Any]) -> dict[str, Any]:
    limits = summary["limits"]
    return {
        "s": summary,
        "definitions": [(k, v.format(**limits)) for k, v in DEFINITIONS],
        "verdict": verdict_table(summary),
        "verdict_notes": verdict_notes(summary),
        "comparison": comparison_table(summary),
        "scenarios": scenario_table(summary),
        "policies": policy_table(summary),
        "reckless": reckless_table(summary),
        "traffic": traffic_table(summary),
        "sumo": sumo_table(summary),
        "perception": perception_table(summary),
        "figures": figure_list(summary),
        "scenario_names": SCENARIO_NAMES,
    }


def _environment(autoescape: bool) -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(TEMPLATES),
        autoescape=autoescape,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )


def render_markdown(summary: dict[str, Any]) -> str:
    """``report.md`` (pictures referenced beside it, in ``figures/``)."""
    return _environment(False).get_template("report.md.j2").render(**_context(summary))


def render_html(summary: dict[str, Any], folder: Path) -> str:
    """``report.html``: one self-contained page, every picture embedded as a data URI."""

    def embed(stem: str, alt: str) -> str:
        path = folder / "figures" / stem
        mime = "image/gif" if path.suffix == ".gif" else "image/png"
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return (
            f'<figure><img alt="{html.escape(alt)}" src="data:{mime};base64,{data}"/>'
            f"<figcaption>{html.escape(alt)}</figcaption></figure>"
        )

    template = _environment(True).get_template("report.html.j2")
    return template.render(embed=embed, **_context(summary))


def comparison_text(summary: dict[str, Any]) -> str:
    """The comparison table as aligned text (printed at the end of a run)."""
    table = comparison_table(summary)
    widths = [max(len(x) for x in col) for col in zip(table.header, *table.rows, strict=True)]
    lines = [
        f"{summary['episodes']} random scenarios (seed {summary['seed']}):",
        "  ".join(h.rjust(w) for h, w in zip(table.header, widths, strict=True)),
    ]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in table.rows]
    lines.append("Paper findings (the paper policy in the paper scenarios):")
    lines += [
        f"  [{'x' if f['reproduced'] else ' '}] {f['finding']}" for f in summary["paper_findings"]
    ]
    return "\n".join(lines)
