"""Peer arms built on Stable-Baselines3 with the hyperparameters of ``zoo_configs/<algo>.yml``: SAC, TQC and
CrossQ online from scratch, and SAC with the offline dataset in its replay buffer."""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TQC, CrossQ
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from envs.collection import make_traffic_env
from experiments.peers import common
from experiments.peers.budget import ONLINE_SB3_ARMS
from sb3_ua2c.checks import check_int
from sb3_ua2c.pipeline import env_settings

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
    """SB3 replay buffer drawing ``offline_ratio`` of each minibatch (all while there are no online rows) from
    fixed offline transitions: RLPD's symmetric sampling (Ball et al., ICML 2023)."""

    def __init__(self, buffer_size: int, observation_space: spaces.Space, action_space: spaces.Space,
                 device: th.device | str = "auto",  # same as default: SB3's ReplayBuffer signature
                 n_envs: int = 1, optimize_memory_usage: bool = False, handle_timeout_termination: bool = True,
                 offline_ratio: float = 0.5) -> None:  # same as default: RLPD's symmetric sampling
        super().__init__(buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage,
                         handle_timeout_termination)
        if isinstance(offline_ratio, bool) or not isinstance(offline_ratio, int | float) or not 0.0 <= offline_ratio <= 1.0:
            raise ValueError(f"offline_ratio must be a number in [0, 1], got {offline_ratio!r}")
        self.offline_ratio = float(offline_ratio)
        self.offline: ReplayBuffer | None = None

    def add_offline(self, transitions: Mapping[str, np.ndarray]) -> None:
        """Store offline transitions (:func:`~experiments.peers.common.episode_transitions`, actions scaled to [-1, 1])."""
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


#: The algorithm of each online SB3 arm
ALGORITHMS = {"sac": SAC, "tqc": TQC, "crossq": CrossQ}


def _train_and_evaluate(arm: str, algo: str, inputs: common.ArmInputs, hyperparams: Mapping[str, Any] | None,
                        conf_file: str | os.PathLike | None, offline_ratio: float | None, notes: str) -> dict[str, Any]:
    check_int("online_steps", inputs.online_steps)
    ds = inputs.load_dataset()
    params = {**common.zoo_hyperparams(algo, ds.metadata.get("env_id", "MixedTraffic-v0"), conf_file),
              **(hyperparams or {})}
    th.set_num_threads(1)
    out = Path(inputs.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    settings = env_settings(ds)
    clock = common.PhaseClock()
    env = Monitor(make_traffic_env(**settings), str(out / "online"), info_keywords=("collision",))
    try:
        ds.check_compatible(env)
        kwargs = copy.deepcopy(params)  # SB3 adds keys to policy_kwargs: keep the record as given
        if offline_ratio is not None:
            kwargs.update(replay_buffer_class=OfflineMixReplayBuffer, replay_buffer_kwargs={"offline_ratio": offline_ratio})
        if algo not in ALGORITHMS:
            raise ValueError(f"algo must be one of {list(ONLINE_SB3_ARMS)}, got {algo!r}")
        model = ALGORITHMS[algo]("MlpPolicy", env, seed=inputs.seed, device="cpu", verbose=0, **kwargs)
        if offline_ratio is not None:
            model.replay_buffer.add_offline(common.episode_transitions(ds.episodes))
        with clock.phase("online"):
            model.learn(inputs.online_steps)
        model.save(out / "model.zip")
    finally:
        env.close()
    with clock.phase("evaluate"):
        evaluation = common.evaluation_record(model, settings, inputs)
    hyper = {"algo": algo, **params}
    if offline_ratio is not None:
        hyper["offline_ratio"] = offline_ratio
    return common.unit_record(arm, inputs, ds, inputs.online_steps, hyper, evaluation,
                              common.learning_curve(out / "online"), clock, notes=notes)


def run_sb3_online(inputs: common.ArmInputs, algo: str = "sac", hyperparams: Mapping[str, Any] | None = None,
                   conf_file: str | os.PathLike | None = None) -> dict[str, Any]:
    """One unit: SB3 SAC, sb3-contrib TQC or CrossQ trained online from scratch, then evaluated."""
    notes = f"{algo.upper()} online from scratch, hyperparameters from zoo_configs/{algo}.yml"
    return _train_and_evaluate(algo, algo, inputs, hyperparams, conf_file, None, notes)


def run_sb3_offline_mix(inputs: common.ArmInputs,
                        offline_ratio: float = 0.5,  # same as default: RLPD's symmetric sampling
                        hyperparams: Mapping[str, Any] | None = None,
                        conf_file: str | os.PathLike | None = None) -> dict[str, Any]:
    """One unit: :func:`run_sb3_online` of SAC with the offline transitions in its buffer (:data:`RLPD_DIFFERENCES`)."""
    return _train_and_evaluate("sac_offline_mix", "sac", inputs, hyperparams, conf_file, offline_ratio, RLPD_DIFFERENCES)
