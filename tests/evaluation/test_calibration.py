"""Perception bounds by split conformal prediction: coverage, refusals, the CLI round trip."""

import json

import numpy as np
import pytest
import yaml

from safeswitch.cli import main
from safeswitch.core.config import ConfigError
from safeswitch.evaluation.calibration import (
    SensorModel,
    calibrate,
    conformal_bound,
    simulate_pairs,
)


@pytest.mark.parametrize("distribution", ["gaussian", "laplace"])
@pytest.mark.parametrize("alpha", [0.01, 0.05, 0.2])
def test_held_out_coverage_is_within_one_percent_of_one_minus_alpha(distribution, alpha):
    sensor = SensorModel(position_sigma_m=0.7, speed_sigma_mps=0.4, distribution=distribution)
    result = calibrate(*simulate_pairs(sensor, 40_000, seed=2), alpha=alpha, seed=2)
    assert abs(result.coverage_position - (1 - alpha)) <= 0.01
    assert abs(result.coverage_speed - (1 - alpha)) <= 0.01
    # both keys at once: at least 1 − 2α (the union bound)
    assert result.coverage_both >= 1 - 2 * alpha - 0.01


def test_the_bound_is_the_conformal_quantile_of_the_errors():
    # n = 19, α = 0.1: rank ⌈20 · 0.9⌉ = 18 → the 18th smallest |error|
    errors = np.arange(1.0, 20.0) * np.where(np.arange(19) % 2, -1, 1)
    assert conformal_bound(errors, 0.1) == 18.0
    assert conformal_bound(errors[:5], 0.1) == np.inf  # too few for α


def test_gaussian_bounds_match_the_normal_quantile():
    sensor = SensorModel(position_sigma_m=1.0, speed_sigma_mps=0.5)
    result = calibrate(*simulate_pairs(sensor, 100_000, seed=4), alpha=0.05, seed=4)
    assert result.position_error_m == pytest.approx(1.96, rel=0.03)
    assert result.speed_error_mps == pytest.approx(0.98, rel=0.03)


def test_bad_pairs_are_refused_with_their_row():
    seen = np.array([1.0, 2.0, np.nan, 4.0])
    with pytest.raises(ConfigError, match="seen_position_m is nan in row 3"):
        calibrate(seen, seen, seen, seen)
    with pytest.raises(ConfigError, match=r"alpha=0\.01 needs at least 99"):
        calibrate(*(np.zeros(50),) * 4, alpha=0.01)


@pytest.mark.slow
def test_calibrate_perception_writes_a_block_that_evaluate_reads(tmp_path, capsys):
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 100, 4000)
    speed = rng.uniform(5, 12, 4000)
    pairs = tmp_path / "pairs.csv"
    rows = ["seen_position_m,true_position_m,seen_speed_mps,true_speed_mps"]
    rows += [
        f"{p + e},{p},{v + f},{v}"
        for p, v, e, f in zip(
            truth, speed, rng.normal(0, 0.5, 4000), rng.normal(0, 0.2, 4000), strict=True
        )
    ]
    pairs.write_text("\n".join(rows) + "\n")
    assert main(["calibrate-perception", "--pairs", str(pairs), "--alpha", "0.1",
                 "--out", str(tmp_path / "cal")]) == 0  # fmt: skip
    block = yaml.safe_load((tmp_path / "cal" / "perception.yaml").read_text())["perception"]
    report = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert block["position_error_m"] == pytest.approx(0.5 * 1.645, rel=0.1)
    assert abs(report["coverage_position"] - 0.9) <= 0.02
    out = tmp_path / "eval"
    code = main(
        [
            "evaluate",
            "--model",
            "certified",
            "--episodes",
            "20",
            "--perception",
            str(tmp_path / "cal" / "perception.yaml"),
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    setting = summary["settings"][0]
    assert setting.startswith("env.perception=")
    assert json.loads(setting.split("=", 1)[1])["position_error_m"] == block["position_error_m"]


def test_a_bad_perception_file_is_one_line_naming_the_key(tmp_path, capsys):
    bad = tmp_path / "p.yaml"
    bad.write_text("perception:\n  latency_s: -1\n")
    code = main(["evaluate", "--model", "certified", "--perception", str(bad), "--out",
                 str(tmp_path / "e")])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "perception.latency_s" in err[0] and "-1" in err[0]
