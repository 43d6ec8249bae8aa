"""The traffic application of sb3-ua2c. Importing this package registers ``MixedTraffic-v0``.

Importing never needs SUMO: the simulator is imported when an environment is constructed.

================== ============================================================================
module             role
================== ============================================================================
``mixed_traffic``  ``MixedTraffic-v0``: an autonomous vehicle merging from an on-ramp into a
                   three-lane highway with 34 human-driven vehicles of three driving styles
``mdp``            observation slots, styles and the reward of the MDP (pure)
``scenario``       the road network and the scenario generator; ``sumo``: the libsumo adapter
``style``          driving-style inference (Eq. 5): the classifier, its data and training
``wrappers``       :class:`DrivingStyleContext`, the style context c_t of Eq. 6 in the observation
``collection``     the SUMO behaviour policy, offline dataset collection, :func:`make_traffic_env`
``evaluation``     reward, jerk, collision, merge and L_t of a checkpoint on seeded scenarios
``cli``            the traffic job's command line, ``python -m envs`` (console script ``ua2c``)
================== ============================================================================
"""

from gymnasium.envs.registration import register, registry

from envs.mdp import SLOT_FEATURES, SLOT_NAMES, STYLES, RewardConfig

__all__ = [
    "STYLES", "SLOT_NAMES", "SLOT_FEATURES", "RewardConfig", "MixedTrafficConfig", "MixedTrafficEnv",
    "DrivingStyleContext", "TRAFFIC_DEFAULTS", "make_traffic_env",
]

if "MixedTraffic-v0" not in registry:
    register(id="MixedTraffic-v0", entry_point="envs.mixed_traffic:MixedTrafficEnv")

_LAZY = {
    "MixedTrafficEnv": "envs.mixed_traffic",
    "MixedTrafficConfig": "envs.mixed_traffic",
    "DrivingStyleContext": "envs.wrappers",
    "TRAFFIC_DEFAULTS": "envs.collection",
    "make_traffic_env": "envs.collection",
}


def __getattr__(name: str):
    # Lazy: gymnasium spaces, torch and sb3_ua2c load on first use, SUMO only with an environment.
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
