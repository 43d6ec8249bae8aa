"""Gymnasium environments of sb3-ua2c. Importing this package registers their ids.

Importing never needs SUMO: the simulator is imported when an environment is constructed.

* ``MixedTraffic-v0``: :class:`envs.mixed_traffic.MixedTrafficEnv`, an autonomous vehicle
  merging from an on-ramp into a three-lane highway with 34 human-driven vehicles of three
  driving styles (SUMO through libsumo).
"""

from gymnasium.envs.registration import register, registry

from envs.mdp import SLOT_FEATURES, SLOT_NAMES, STYLES, RewardConfig

__all__ = ["STYLES", "SLOT_NAMES", "SLOT_FEATURES", "RewardConfig", "MixedTrafficConfig", "MixedTrafficEnv"]

if "MixedTraffic-v0" not in registry:
    register(id="MixedTraffic-v0", entry_point="envs.mixed_traffic:MixedTrafficEnv")


def __getattr__(name: str):
    # Lazy: importing the env module pulls gymnasium spaces but never SUMO.
    if name in ("MixedTrafficEnv", "MixedTrafficConfig"):
        from envs import mixed_traffic

        return getattr(mixed_traffic, name)
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
