"""Peers of UA2C on the Figure-2 protocol, one unit per arm and seed: ``python -m experiments peers``."""

from experiments.peers.common import ArmInputs, zoo_hyperparams
from experiments.peers.sb3_arms import OfflineMixReplayBuffer, run_sb3_offline_mix, run_sb3_online


def run_d3rlpy(*args, **kwargs):
    """:func:`experiments.peers.d3rlpy_arms.run_d3rlpy` (imported on first use: d3rlpy is optional)."""
    from experiments.peers.d3rlpy_arms import run_d3rlpy as run

    return run(*args, **kwargs)


__all__ = ["ArmInputs", "OfflineMixReplayBuffer", "run_d3rlpy", "run_sb3_offline_mix", "run_sb3_online", "zoo_hyperparams"]
