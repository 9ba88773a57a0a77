"""The report's tables mark a failure — a loss of control as much as a collision — the way
they mark a collision."""

from safeswitch.app.reproduce import TRAFFIC_POLICIES, training_record
from safeswitch.report.document import (
    comparison_table,
    policy_table,
    reckless_table,
    sumo_table,
    traffic_table,
)


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


def made(method, collisions):
    return {"method": method, "adas_penalty": True, "collisions": collisions}


def test_the_policy_table_lists_the_traffic_policies_and_marks_collisions_in_training():
    summary = {
        "controllers": {
            "rule": {"label": "PID_th", "switching": "paper", "training": None},
            "ppo-unshielded": {"switching": "none", "training": made("PPO", 853)},
        },
        "traffic": {"policies": {
            "ppo-traffic-certified": {"switching": "certified", "training": made("PPO", 0)},
        }},
    }  # fmt: skip
    table = policy_table(summary)
    assert [r[0] for r in table.rows] == ["rule", "ppo-unshielded", "ppo-traffic-certified"]
    assert table.rows[2][2] == "certified"
    assert table.alert == [False, True, False]
    del summary["traffic"]["policies"]  # a summary.json written before the traffic rows
    assert len(policy_table(summary).rows) == 2


def test_the_shipped_traffic_policies_say_how_they_were_made():
    from safeswitch.training.shipped import SHIPPED_DIR

    method = {name: training_record(SHIPPED_DIR / shipped)["method"]
              for name, shipped in TRAFFIC_POLICIES.items()}  # fmt: skip
    certified = method["ppo-traffic-certified"]
    assert certified.startswith("in traffic from every leg: PPO from a random initialisation")
    assert "a learned go predictor in its observation" in certified
    assert "curve speed limiter (2.8 m/s² sideways)" in certified
    assert "behaviour cloning of the gap planner" in method["clone-traffic-certified"]
    assert "go predictor" not in method["clone-traffic-certified"]


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


def test_every_driving_table_shows_comfort_in_ticks_and_episodes_and_marks_an_excess():
    def comfort(share, episodes):
        return {**row(0, 0), "comfort_violation_fraction": share,
                "comfort_violation_episodes": episodes}  # fmt: skip

    traffic = traffic_table({"traffic": {"rows": [
        {"preset": "test", "controller": "learned", "switching": "certified",
         **comfort(0.0057, 205)},
        {"preset": "test", "controller": "gap", "switching": "certified", **comfort(0.0049, 40)},
        {"preset": "test", "controller": "old", "switching": "certified",
         **row(0, 0), "comfort_violation_fraction": 0.001},  # written before episodes counted
    ]}})  # fmt: skip
    ticks = traffic.header.index("comfort exceeded (ticks)")
    episodes = traffic.header.index("comfort exceeded (episodes)")
    assert [r[ticks] for r in traffic.rows] == ["0.57%", "0.49%", "0.10%"]
    assert [r[episodes] for r in traffic.rows] == ["205", "40", "–"]
    assert [b[ticks] for b in traffic.bad] == [True, False, False]  # over the 0.5 % budget
    assert not any(b[episodes] for b in traffic.bad)  # a count of episodes has no budget
    assert traffic.alert == [False, False, False]  # red cells, not a failed row

    compared = comparison_table({"controllers": {"ppo": {"random": comfort(0.001, 17)}}})
    assert compared.rows[0][compared.header.index("comfort exceeded (episodes)")] == "17"


def test_clearing_sooner_than_the_oracle_is_red_only_when_a_limit_was_broken():
    """The oracle's point mass on the route's centre line is not the car: a policy that takes
    a line within the lane clears sooner without breaking a rule (the shipped `certified`
    policy, 258 of 1,000). The cell is red when any of those episodes sped or broke a comfort
    limit — and, for a summary without that split, whenever there are any."""

    def sooner(episodes, broken=None):
        split = {} if broken is None else {"faster_than_oracle_either": broken}
        return {"random": {**row(0, 0), "faster_than_oracle_episodes": episodes, **split}}

    table = comparison_table({"controllers": {
        "lane line": sooner(258, 0), "speeder": sooner(40, 40), "old": sooner(3),
        "none": sooner(0, 0),
    }})  # fmt: skip
    column = table.header.index("faster than the oracle")
    assert [r[column] for r in table.rows] == ["258", "40", "3", "0"]
    assert [b[column] for b in table.bad] == [False, True, True, False]
