"""Fine-tune a `traffic-certified` run with the simulated go check in its observation (issue
#39; docs/learning_experiments.md, "The exact go check in place of the predictor").

Every task in traffic this process builds has the last value of its observation — the go
predictor's probability — replaced by the gap planner's simulated go check from the same state
(``foresight: observed``: only what a car could see), recomputed at each of the policy's
decisions and held in between. Then ``experimental/traffic_certified_exact_go`` trains from the
run ``RUN`` (seed ``SEED``) into ``OUT``, and the run's policy is evaluated, the check still in
place, on 1,000 scenes of each traffic family (seed 1000003) into ``OUT/families.json``.

Run: ``python experiments/finetune_exact_go.py RUN SEED OUT``.
"""

import sys
from dataclasses import replace
from pathlib import Path

from probe_exact_go_feature import exact_go

from safeswitch.app.evaluate import evaluate
from safeswitch.io import write_json
from safeswitch.leftturn.traffic import LeftTurnTrafficTask
from safeswitch.training import train
from safeswitch.training.config import load_any_config

FAMILIES = ("test", "light", "medium", "heavy")
KEPT = ("collisions", "safety_activation_episodes", "comfort_violation_fraction",
        "comfort_violation_episodes", "cleared_episodes", "mean_efficiency", "max_speed_kmh",
        "faster_than_oracle_either")  # fmt: skip
_built = LeftTurnTrafficTask.__init__


def _with_check(self, *args, **kwargs) -> None:
    _built(self, *args, **kwargs)
    exact_go(self)


def main() -> None:
    start, seed, out = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
    LeftTurnTrafficTask.__init__ = _with_check
    config = load_any_config("experimental/traffic_certified_exact_go")
    config = replace(config, seed=seed, torch_threads=1,
                     warm_start=replace(config.warm_start, policy=start))  # fmt: skip
    metrics = train(config, out, progress_bar=False)
    result = {"selected": metrics["selected"], "wall_time_s": metrics["wall_time_s"],
              "training": metrics["training"]}  # fmt: skip
    for family in FAMILIES:
        e = evaluate("learned", str(out), "random", 1000, 1_000_003, None, None, traffic=family)
        result[family] = {k: e[k] for k in KEPT}
        print(family, result[family], flush=True)
    write_json(out / "families.json", result)


if __name__ == "__main__":
    main()
