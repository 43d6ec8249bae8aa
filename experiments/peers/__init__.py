"""Peers of UA2C on the Figure-2 protocol (issue 21): one function per arm kind trains one unit
(one arm, one seed) and returns its record.

* :func:`~experiments.peers.sb3_arms.run_sb3_online`: SB3 SAC / sb3-contrib TQC, online from scratch;
* :func:`~experiments.peers.sb3_arms.run_sb3_offline_mix`: SAC with the offline data in its buffer
  (RLPD's symmetric sampling);
* :func:`~experiments.peers.d3rlpy_arms.run_d3rlpy`: d3rlpy IQL / Cal-QL, offline then online
  (``pip install --no-deps d3rlpy==2.8.1 gym==0.26.2``, see :mod:`experiments.peers.d3rlpy_arms`);
* :func:`~experiments.peers.ua2c_arms.run_ua2c_arm`: the UA2C arms of Figure 2 (adaptive, fixed, one-step),
  offline checkpoint then online, with the same record;
* :mod:`experiments.common.stats`: IQM, stratified bootstrap CIs and probability of improvement (rliable).

The command ``python -m experiments peers`` (:mod:`~experiments.peers.cli`) runs every (arm, seed) as one
unit (:mod:`~experiments.peers.runner`, budget and estimate in :mod:`~experiments.peers.budget`) and writes
the report (:mod:`~experiments.peers.report`); see ``docs/peers.md``.

Every unit reads the seed's dataset (which defines the environment), trains for the same online
step budget and evaluates on the same held-out scenarios as the UA2C arms, with
:func:`envs.evaluation.evaluate`. Run units through :mod:`experiments.common.runner`.
"""

from experiments.peers.common import EvalProtocol, zoo_hyperparams
from experiments.peers.sb3_arms import OfflineMixReplayBuffer, run_sb3_offline_mix, run_sb3_online


def run_d3rlpy(*args, **kwargs):
    """:func:`experiments.peers.d3rlpy_arms.run_d3rlpy` (imported on first use: d3rlpy is optional)."""
    from experiments.peers.d3rlpy_arms import run_d3rlpy as run

    return run(*args, **kwargs)


__all__ = ["EvalProtocol", "OfflineMixReplayBuffer", "run_d3rlpy", "run_sb3_offline_mix", "run_sb3_online", "zoo_hyperparams"]
