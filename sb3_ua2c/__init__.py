"""sb3-ua2c: uncertainty-aware adaptive action chunking (UA2C) for Stable-Baselines3."""

from sb3_ua2c.version import __version__

__all__ = ["__version__"]
