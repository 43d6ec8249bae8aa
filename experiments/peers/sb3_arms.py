"""Peer arms built on Stable-Baselines3: SAC and TQC online from scratch, and SAC with the offline
dataset in its replay buffer (RLPD's symmetric sampling).

Hyperparameters come from ``zoo_configs/{sac,tqc}.yml`` (:func:`~experiments.peers.common.zoo_hyperparams`),
overridable key by key, and are stated in the unit's record. The environment is the dataset's
(same observation, with or without the style context c_t, and the same ``Box`` action space); the
zoo file's ``env_wrapper`` is not applied, so every arm sees the observation of the data.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from experiments.peers.budget import ONLINE_SB3_ARMS
from experiments.peers.common import (
    ArmInputs,
    PhaseClock,
    episode_transitions,
    evaluation_record,
    learning_curve,
    read_dataset,
    unit_record,
    zoo_hyperparams,
)
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import OfflineDataset

#: Differences of the offline-mix arm from RLPD (Ball et al. 2023), stated in its record.
RLPD_DIFFERENCES = (
    "SB3 SAC with RLPD's symmetric sampling (half of each batch from the offline data, half from the online "
    "buffer) and the SAC zoo hyperparameters; unlike RLPD: two critics without LayerNorm (RLPD: an ensemble of "
    "10 LayerNorm critics, 2 drawn per target), one gradient step per env step (RLPD: UTD 20), the entropy "
    "term kept in the target, and the zoo's learning_starts random steps"
)


def scale_actions(actions: np.ndarray, action_space: spaces.Box) -> np.ndarray:
    """Environment-unit actions -> SB3's buffer units for squashed policies (SAC, TQC): [low, high] -> [-1, 1]."""
    low, high = action_space.low.astype(np.float64), action_space.high.astype(np.float64)
    return (2.0 * (np.asarray(actions, dtype=np.float64) - low) / (high - low) - 1.0).astype(np.float32)


class OfflineMixReplayBuffer(ReplayBuffer):
    """SB3 replay buffer whose minibatches draw ``offline_ratio`` of their rows from fixed offline
    transitions and the rest from the online transitions added as usual (RLPD's symmetric
    sampling: half of each batch offline). While the online part is empty, the whole batch is offline.

    Paper: Ball et al., "Efficient Online Reinforcement Learning with Offline Data" (RLPD), ICML 2023.

    :param offline_ratio: fraction of each batch drawn from the offline transitions, in [0, 1]
    (the other parameters are :class:`~stable_baselines3.common.buffers.ReplayBuffer`'s)
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",  # same as default: SB3's ReplayBuffer signature
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        offline_ratio: float = 0.5,  # same as default: RLPD's symmetric sampling
    ) -> None:
        super().__init__(buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage,
                         handle_timeout_termination)
        if isinstance(offline_ratio, bool) or not isinstance(offline_ratio, int | float) or not 0.0 <= offline_ratio <= 1.0:
            raise ValueError(f"offline_ratio must be a number in [0, 1], got {offline_ratio!r}")
        self.offline_ratio = float(offline_ratio)
        self.offline: ReplayBuffer | None = None

    def add_offline(self, transitions: Mapping[str, np.ndarray]) -> None:
        """Store offline transitions (:func:`~experiments.peers.common.episode_transitions`; actions in the
        environment's units, scaled here to [-1, 1] as SB3 stores them for SAC and TQC)."""
        n = len(transitions["rewards"])
        if n == 0:
            raise ValueError("offline transitions must not be empty")
        buf = ReplayBuffer(n, self.observation_space, self.action_space, self.device, n_envs=1,
                           handle_timeout_termination=False)
        buf.observations[:, 0] = transitions["observations"]  # (n, obs_dim) -> (n, 1, obs_dim)
        buf.next_observations[:, 0] = transitions["next_observations"]
        buf.actions[:, 0] = scale_actions(transitions["actions"], self.action_space).reshape(n, -1)
        buf.rewards[:, 0] = transitions["rewards"]
        buf.dones[:, 0] = transitions["terminations"]  # truncations bootstrap: not done
        buf.full, buf.pos = True, 0
        self.offline = buf

    def sample(self, batch_size: int, env: Any = None) -> ReplayBufferSamples:
        if self.offline is None:
            raise RuntimeError("OfflineMixReplayBuffer.sample before add_offline(): no offline transitions")
        n_offline = batch_size if self.size() == 0 else int(round(self.offline_ratio * batch_size))
        parts = [self.offline.sample(n_offline, env)] if n_offline else []
        if n_offline < batch_size:
            parts.append(super().sample(batch_size - n_offline, env))
        # each field (n_offline, ...) + (batch - n_offline, ...) -> (batch, ...); optional fields stay None
        return ReplayBufferSamples(*(
            None if fields[0] is None else th.cat(fields) for fields in zip(*parts, strict=True)))


def _algorithm(algo: str) -> type:
    if algo == "sac":
        from stable_baselines3 import SAC

        return SAC
    if algo == "tqc":
        from sb3_contrib import TQC

        return TQC
    if algo == "crossq":
        from sb3_contrib import CrossQ

        return CrossQ
    raise ValueError(f"algo must be one of {list(ONLINE_SB3_ARMS)}, got {algo!r}")


def _train_and_evaluate(arm: str, algo: str, inputs: ArmInputs, ds: OfflineDataset, params: dict[str, Any],
                        offline_ratio: float | None, notes: str) -> dict[str, Any]:
    from envs.collection import make_traffic_env
    from sb3_ua2c.pipeline import env_settings

    th.set_num_threads(1)
    seed, online_steps, protocol = inputs.seed, inputs.online_steps, inputs.protocol
    out = Path(inputs.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    settings = env_settings(ds)
    clock = PhaseClock()
    env = Monitor(make_traffic_env(**settings), str(out / "online"), info_keywords=("collision",))
    try:
        ds.check_compatible(env)
        kwargs = copy.deepcopy(params)  # SB3 adds keys to policy_kwargs: keep the record as given
        if offline_ratio is not None:
            kwargs.update(replay_buffer_class=OfflineMixReplayBuffer, replay_buffer_kwargs={"offline_ratio": offline_ratio})
        model = _algorithm(algo)("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)  # same as default: quiet
        if offline_ratio is not None:
            model.replay_buffer.add_offline(episode_transitions(ds.episodes))
        with clock.phase("online"):
            model.learn(online_steps)
        model.save(out / "model.zip")
    finally:
        env.close()
    with clock.phase("evaluate"):
        evaluation = evaluation_record(model, settings, protocol)
    hyper = {"algo": algo, **params}
    if offline_ratio is not None:
        hyper["offline_ratio"] = offline_ratio
    return unit_record(arm, seed, ds, protocol, online_steps, hyper, evaluation, learning_curve(out / "online"),
                       clock, notes=notes)


def run_sb3_online(inputs: ArmInputs, algo: str = "sac", hyperparams: Mapping[str, Any] | None = None,
                   conf_file: str | os.PathLike | None = None) -> dict[str, Any]:
    """One unit: SB3 SAC, sb3-contrib TQC or sb3-contrib CrossQ trained online from scratch for ``online_steps`` env
    steps on the dataset's environment, then evaluated on the held-out scenarios.

    The dataset only defines the environment (and is recorded); its transitions are not used.

    :param inputs: the unit's directory (``model.zip``, ``online.monitor.csv``), dataset, seed, online steps
        and evaluation scenarios (:class:`~experiments.peers.common.ArmInputs`)
    :param algo: ``"sac"``, ``"tqc"`` or ``"crossq"``
    :param hyperparams: constructor arguments that replace the zoo file's, key by key
    :param conf_file: zoo YAML file (default ``zoo_configs/<algo>.yml``)
    :return: the unit's record (:func:`~experiments.peers.common.unit_record`)
    """
    check_int("online_steps", inputs.online_steps)
    ds = read_dataset(inputs.dataset)
    params = {**zoo_hyperparams(algo, ds.metadata.get("env_id", "MixedTraffic-v0"), conf_file), **(hyperparams or {})}
    notes = f"{algo.upper()} online from scratch, hyperparameters from zoo_configs/{algo}.yml"
    return _train_and_evaluate(algo, algo, inputs, ds, params, None, notes)


def run_sb3_offline_mix(
    inputs: ArmInputs,
    offline_ratio: float = 0.5,  # same as default: RLPD's symmetric sampling
    hyperparams: Mapping[str, Any] | None = None,
    conf_file: str | os.PathLike | None = None,
) -> dict[str, Any]:
    """One unit: SB3 SAC with the seed's offline transitions in its replay buffer, ``offline_ratio``
    of every minibatch drawn from them (:class:`OfflineMixReplayBuffer`), trained online for
    ``online_steps`` env steps, then evaluated on the held-out scenarios. What differs from RLPD is
    in :data:`RLPD_DIFFERENCES` (also in the record's ``notes``).

    Parameters as :func:`run_sb3_online` (the algorithm is SAC), plus:

    :param offline_ratio: fraction of each batch drawn from the offline data (RLPD: 0.5)
    """
    check_int("online_steps", inputs.online_steps)
    ds = read_dataset(inputs.dataset)
    params = {**zoo_hyperparams("sac", ds.metadata.get("env_id", "MixedTraffic-v0"), conf_file), **(hyperparams or {})}
    return _train_and_evaluate("sac_offline_mix", "sac", inputs, ds, params, offline_ratio, RLPD_DIFFERENCES)
