"""The left turn decides exactly as before the framework redesign (see ``golden.py``)."""

import numpy as np
import pytest

from tests.leftturn.golden import COLUMNS, PATH, digest, runs


@pytest.fixture(scope="module")
def recorded_runs():
    return {name: (config, make) for name, config, make in runs()}


@pytest.mark.parametrize("name", list(np.load(PATH).keys()))
def test_every_decision_is_bit_for_bit_what_the_pre_redesign_code_made(recorded_runs, name):
    config, make_policy = recorded_runs[name]
    recorded = np.load(PATH)[name]
    now = digest(config, make_policy)
    for j, column in enumerate(COLUMNS):
        differ = np.flatnonzero(now[:, j] != recorded[:, j])
        assert differ.size == 0, f"{name}: {column} differs in episodes {differ[:10].tolist()}"
