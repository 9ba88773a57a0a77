"""The left-turn case study (paper Section IV): controllers, switching logics, rewards,
scenarios, the Gymnasium environment and the natively batched VecEnv."""

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.env import LeftTurnEnv
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.leftturn.vec_env import LeftTurnVecEnv, make_vec_env

__all__ = ["LeftTurnConfig", "LeftTurnEnv", "LeftTurnTask", "LeftTurnVecEnv", "make_vec_env"]
