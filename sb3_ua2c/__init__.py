"""sb3-ua2c: uncertainty-aware adaptive action chunking (UA2C) for Stable-Baselines3.

The traffic application (``MixedTraffic-v0``, driving-style inference) is the package ``envs``.
"""

from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.policies import MlpPolicy, UA2CPolicy
from sb3_ua2c.ua2c import UA2C
from sb3_ua2c.version import __version__

__all__ = ["UA2C", "ExecutionRule", "MlpPolicy", "UA2CPolicy", "__version__"]
