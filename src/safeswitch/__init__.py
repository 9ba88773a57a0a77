"""safeswitch: safe reinforcement learning with a rule-based Safety controller, a learned
controller and a switching logic between them (Aksjonov & Kyrki), on an embedded simulator.

Importing the package registers the Gymnasium id ``safeswitch/LeftTurn-v0``.
"""

import gymnasium as _gym

__version__ = "0.1.0"

ENV_ID = "safeswitch/LeftTurn-v0"

if ENV_ID not in _gym.registry:
    _gym.register(id=ENV_ID, entry_point="safeswitch.leftturn.env:LeftTurnEnv")
