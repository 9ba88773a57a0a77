"""The report's tables mark a failure — a loss of control as much as a collision — the way
they mark a collision."""

from safeswitch.report.document import reckless_table, sumo_table, traffic_table


def row(collisions, lost):
    return {
        "collisions": collisions,
        "lost_control_episodes": lost,
        "failures": collisions + lost,
        "safety_activation_episodes": 3,
    }


def test_the_reckless_table_shows_and_marks_a_loss_of_control():
    summary = {"reckless_full_throttle": [
        {"switching": "none", **row(5, 0)},
        {"switching": "paper", **row(0, 7)},
        {"switching": "certified", **row(0, 0)},
    ]}  # fmt: skip
    table = reckless_table(summary)
    assert "lost control" in table.header and "failures" in table.header
    paper = table.rows[1]
    assert paper[table.header.index("lost control")] == "7"
    assert table.alert == [True, True, False]


def test_traffic_and_simulator_rows_are_marked_for_a_loss_of_control_alone():
    traffic = {"traffic": {"rows": [
        {"preset": "light", "controller": "rule", "switching": "paper", **row(0, 2)},
        {"preset": "light", "controller": "rule", "switching": "certified", **row(0, 0)},
    ]}}  # fmt: skip
    assert traffic_table(traffic).alert == [True, False]
    sumo = {"sumo": {"rows": [
        {"controller": "rule", "sim": "sumo", **row(0, 1)},
        {"controller": "rule", "sim": "embedded", **row(0, 0)},
    ]}}  # fmt: skip
    assert sumo_table(sumo).alert == [True, False]
