"""The car-following plant (``tests/core/plants.py``: the README's own-plant example with
random starts and a 200-step horizon) registered as a user registers a plant, so that the
command line and the benchmarks can train it by name:
``--env tests.core.follow_plant:Follow-v0 --switching braking-envelope``. Its failure is the
plant's ``info["crashed"]``, declared explicitly.
"""

from __future__ import annotations

from tests.core.plants import BrakingEnvelope, Follow, full_brake, register_plant

ENV_ID = "Follow-v0"
LOGIC = "braking-envelope"


def register() -> None:
    """Register the plant, its Safety controller (with its failure) and its logic."""
    register_plant(ENV_ID, Follow, full_brake, "crashed", LOGIC, BrakingEnvelope)


register()
