"""safeswitch: safe reinforcement learning with a rule-based Safety controller, a learned
controller and a switching logic between them (Aksjonov & Kyrki), on an embedded simulator."""

__version__ = "0.1.0"
