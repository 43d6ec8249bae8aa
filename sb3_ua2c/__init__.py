"""sb3-ua2c: uncertainty-aware adaptive action chunking (UA2C) for Stable-Baselines3."""

from sb3_ua2c.policies import MlpPolicy, UA2CPolicy
from sb3_ua2c.style import DrivingStyleClassifier
from sb3_ua2c.ua2c import UA2C
from sb3_ua2c.version import __version__
from sb3_ua2c.wrappers import DrivingStyleContext

__all__ = ["UA2C", "MlpPolicy", "UA2CPolicy", "DrivingStyleClassifier", "DrivingStyleContext", "__version__"]
