"""Peers of UA2C on the Figure-2 protocol: one function per arm kind trains one unit (one arm, one seed)
and returns its record; ``python -m experiments peers`` (:mod:`~experiments.peers.cli`) runs them (see
``docs/peers.md``)."""

from experiments.peers.common import ArmInputs, zoo_hyperparams
from experiments.peers.sb3_arms import OfflineMixReplayBuffer, run_sb3_offline_mix, run_sb3_online


def run_d3rlpy(*args, **kwargs):
    """:func:`experiments.peers.d3rlpy_arms.run_d3rlpy` (imported on first use: d3rlpy is optional)."""
    from experiments.peers.d3rlpy_arms import run_d3rlpy as run

    return run(*args, **kwargs)


__all__ = ["ArmInputs", "OfflineMixReplayBuffer", "run_d3rlpy", "run_sb3_offline_mix", "run_sb3_online", "zoo_hyperparams"]
