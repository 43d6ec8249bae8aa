"""Peer arms built on d3rlpy (``docs/peers.md``): IQL, Cal-QL and ReBRAC offline then online, RLPD online only,
and behaviour cloning (BC) offline only, as a reference row."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.monitor import Monitor

from envs.collection import make_traffic_env
from experiments.common.cli import D3RLPY_INSTALL
from experiments.peers import common
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import Episode, OfflineDataset
from sb3_ua2c.pipeline import env_settings

ALGOS = ("iql", "calql", "rebrac", "rlpd", "bc")
#: algorithms fitted offline only (no ``fit_online``): their final evaluation is the offline one
OFFLINE_ONLY = ("bc",)
#: What the ``rlpd`` arm changes from RLPD as published (Ball et al., 2023), stated in its record.
RLPD_DIFFERENCES = (
    "d3rlpy SAC with RLPD's layer-norm critics, symmetric sampling (half of each batch from the offline data) "
    "and no offline pre-training; unlike RLPD: 2 critics, both in every target (RLPD: an ensemble of 10, 2 drawn "
    "per target), and the update-to-data ratio of the budget (RLPD: 20)"
)
INSTALL = f'pip install "sb3-ua2c[peers]" && {D3RLPY_INSTALL}'


def import_d3rlpy() -> Any:
    """``d3rlpy`` with its structured log quietened to warnings, or an ``ImportError`` naming the install."""
    try:
        import d3rlpy
        import structlog
    except ImportError as exc:
        raise ImportError(f"the d3rlpy arms need d3rlpy: {INSTALL}") from exc
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    return d3rlpy


class D3rlpyPolicy:
    """A built d3rlpy algorithm behind SB3's ``predict`` (what :func:`envs.evaluation.evaluate` calls)."""

    def __init__(self, algo: Any, observation_space: spaces.Space, action_space: spaces.Box) -> None:
        self.algo = algo
        self.observation_space = observation_space
        self.action_space = action_space

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """The greedy action (``deterministic``) or one drawn from the policy, for one or ``n`` observations."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.shape == self.observation_space.shape
        batch = obs[None] if single else obs  # (n, *obs_shape)
        act = np.asarray(self._act(batch, deterministic), dtype=self.action_space.dtype)  # (n, action_dim)
        act = np.clip(act, self.action_space.low, self.action_space.high)
        return (act[0] if single else act), None

    def _act(self, batch: np.ndarray, deterministic: bool) -> np.ndarray:
        """Actions of a batch of observations ``(n, *obs_shape) -> (n, action_dim)``, before clipping."""
        return self.algo.predict(batch) if deterministic else self.algo.sample_action(batch)


class BestOfNPolicy(D3rlpyPolicy):
    """UA2C's way of acting for a d3rlpy peer: the best of ``n`` actions drawn from its policy, under its critic."""

    def __init__(self, algo: Any, observation_space: spaces.Space, action_space: spaces.Box, n: int) -> None:
        super().__init__(algo, observation_space, action_space)
        check_int("best_of_n", n)
        self.n = n

    def _act(self, batch: np.ndarray, deterministic: bool) -> np.ndarray:
        repeated = np.repeat(batch, self.n, axis=0)  # (m * n, *obs_shape)
        actions = np.asarray(self.algo.sample_action(repeated))  # (m * n, action_dim)
        values = np.asarray(self.algo.predict_value(repeated, actions)).reshape(len(batch), self.n)
        return actions.reshape(len(batch), self.n, -1)[np.arange(len(batch)), values.argmax(axis=1)]  # (m, a)


def d3rlpy_episodes(episodes: Sequence[Episode]) -> list[Any]:
    """Our episodes as d3rlpy ``Episode`` objects, a truncated one with its final observation as an extra row
    (d3rlpy drops the last transition of an episode not terminated)."""
    from d3rlpy.dataset import Episode as D3Episode

    out = []
    for ep in episodes:
        terminated = bool(ep.terminations[-1])
        obs = ep.observations[:-1] if terminated else ep.observations  # (T or T + 1, obs_dim)
        pad = 0 if terminated else 1
        actions = np.concatenate([ep.actions, np.zeros((pad, *ep.actions.shape[1:]), ep.actions.dtype)])
        rewards = np.concatenate([ep.rewards, np.zeros(pad)]).astype(np.float32).reshape(-1, 1)
        out.append(D3Episode(observations=obs.astype(np.float32), actions=actions.astype(np.float32),
                             rewards=rewards, terminated=terminated))
    return out


def _mixed_buffer(d3rlpy: Any, online: Any, offline: Any, offline_ratio: float) -> Any:
    """d3rlpy's ``MixedReplayBuffer`` that samples from the offline data alone while the online part is empty."""

    class OfflineFirstMixedBuffer(d3rlpy.dataset.MixedReplayBuffer):
        def sample_transition_batch(self, batch_size: int) -> Any:
            if self._primary_replay_buffer.transition_count == 0:
                return self._secondary_replay_buffer.sample_transition_batch(batch_size)
            return super().sample_transition_batch(batch_size)

    return OfflineFirstMixedBuffer(online, offline, secondary_mix_ratio=offline_ratio)


def published_settings(d3rlpy: Any, algo: str) -> dict[str, Any]:
    """The settings an algorithm is published with where d3rlpy's defaults are not them (``docs/peers.md``)."""
    vector = d3rlpy.models.VectorEncoderFactory
    if algo == "rlpd":
        return {
            "actor_learning_rate": 3e-4, "critic_learning_rate": 3e-4, "temp_learning_rate": 3e-4,
            "actor_encoder_factory": vector([256, 256]),
            "critic_encoder_factory": vector([256, 256], use_layer_norm=True),
            "n_critics": 2, "initial_temperature": 1.0, "tau": 0.005,  # same as default: RLPD's, d3rlpy's names
        }
    if algo == "calql":  # d3rlpy's Cal-QL reproduction (its reward shift is AntMaze's, not taken)
        return {"actor_learning_rate": 3e-4, "critic_learning_rate": 3e-4, "alpha_threshold": 0.8}
    if algo != "rebrac":
        return {}
    return {
        "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3,
        "actor_encoder_factory": vector([256, 256, 256]),
        "critic_encoder_factory": vector([256, 256, 256], use_layer_norm=True),
        "target_smoothing_sigma": 0.2, "target_smoothing_clip": 0.5, "update_actor_interval": 2,
        "actor_beta": 0.01, "critic_beta": 0.01,
        "observation_scaler": d3rlpy.preprocessing.StandardObservationScaler(),
    }


def make_config(d3rlpy: Any, algo: str, action_space: spaces.Box, batch_size: int, config_kwargs: Mapping[str, Any]) -> Any:
    """The d3rlpy config of ``algo``: its :func:`published_settings`, ``batch_size``, then ``config_kwargs``."""
    configs = {"iql": d3rlpy.algos.IQLConfig, "calql": d3rlpy.algos.CalQLConfig, "rebrac": d3rlpy.algos.ReBRACConfig,
               "rlpd": d3rlpy.algos.SACConfig, "bc": d3rlpy.algos.BCConfig}
    if algo not in configs:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    scaler = d3rlpy.preprocessing.MinMaxActionScaler(minimum=action_space.low.astype(np.float32),
                                                     maximum=action_space.high.astype(np.float32))
    settings = {**published_settings(d3rlpy, algo), **dict(config_kwargs)}
    try:
        return configs[algo](batch_size=batch_size, action_scaler=scaler, **settings)
    except TypeError as exc:
        raise ValueError(f"config_kwargs: {exc}") from exc


def run_d3rlpy(inputs: common.ArmInputs, algo: str = "iql", offline_steps: int = 6000,
               offline_ratio: float = 0.5,  # same as default: RLPD's symmetric sampling
               batch_size: int = 256,  # same as default: the SAC zoo entry's
               updates_per_step: int = 1, best_of_n: int = 0,
               config_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One unit: d3rlpy ``algo`` fitted offline on the seed's dataset and evaluated, then (unless
    :data:`OFFLINE_ONLY`) fine-tuned online and evaluated again, also by :class:`BestOfNPolicy` with ``best_of_n``."""
    seed, online_steps = inputs.seed, inputs.online_steps
    for name, value in (("online_steps", online_steps), ("batch_size", batch_size),
                        ("updates_per_step", updates_per_step)):
        check_int(name, value)
    check_int("offline_steps", offline_steps, low=0)
    check_int("best_of_n", best_of_n, low=0)
    if isinstance(offline_ratio, bool) or not isinstance(offline_ratio, int | float) or not 0.0 <= offline_ratio <= 1.0:
        raise ValueError(f"offline_ratio must be a number in [0, 1], got {offline_ratio!r}")
    if algo in OFFLINE_ONLY and offline_steps == 0:
        raise ValueError(f"offline_steps must be >= 1 for {algo!r}, which has no online phase")
    ds = inputs.load_dataset()
    d3rlpy = import_d3rlpy()
    th.set_num_threads(1)
    d3rlpy.seed(seed)
    out = Path(inputs.out_dir)
    logs = d3rlpy.logging.FileAdapterFactory(root_dir=str(out / "d3rlpy"))
    settings = env_settings(ds)
    learner = make_config(d3rlpy, algo, ds.action_space, batch_size, config_kwargs or {}).create(device="cpu:0")
    offline = d3rlpy.dataset.create_infinite_replay_buffer(episodes=d3rlpy_episodes(ds.episodes))
    policy = D3rlpyPolicy(learner, ds.observation_space, ds.action_space)
    clock = common.PhaseClock()
    offline_evaluation = None
    if offline_steps:
        with clock.phase("offline"):
            learner.fit(offline, n_steps=offline_steps, n_steps_per_epoch=offline_steps, experiment_name="offline",
                        with_timestamp=False, logger_adapter=logs, show_progress=False)
        with clock.phase("evaluate_offline"):
            offline_evaluation = common.evaluation_record(policy, settings, inputs)
    hyper = {"algo": algo, "d3rlpy": d3rlpy.__version__, "config": learner.config.serialize_to_dict()}
    if algo in OFFLINE_ONLY:
        notes = f"d3rlpy {algo}: {offline_steps} offline gradient steps, no online phase (a reference row)"
        return common.unit_record(algo, inputs, ds, 0, hyper, offline_evaluation, [], clock,
                                  offline_steps=offline_steps, offline_evaluation=offline_evaluation, notes=notes)
    with clock.phase("online"):
        _fit_online(d3rlpy, learner, ds, settings, offline, seed, out, logs, online_steps, offline_ratio,
                    updates_per_step)
    with clock.phase("evaluate"):
        evaluation = common.evaluation_record(policy, settings, inputs)
    extra = {}
    if best_of_n:
        with clock.phase("evaluate_best_of_n"):
            best = BestOfNPolicy(learner, ds.observation_space, ds.action_space, best_of_n)
            extra["evaluation_best_of_n"] = {"n": best_of_n, **common.evaluation_record(best, settings, inputs)}
    hyper.update(offline_ratio=float(offline_ratio), updates_per_step=updates_per_step)
    settings_text = "the settings of d3rlpy's reproduction" if published_settings(d3rlpy, algo) else "d3rlpy's defaults"
    if algo == "rlpd":
        notes = RLPD_DIFFERENCES + f"; {updates_per_step} updates per env step here"
    else:
        notes = (f"d3rlpy {algo}: {offline_steps} offline gradient steps, then fit_online with {updates_per_step} "
                 f"update(s) per env step and {offline_ratio:g} of each batch from the offline data; {settings_text}")
    record = common.unit_record(algo, inputs, ds, online_steps, hyper, evaluation, common.learning_curve(out / "online"),
                                clock, offline_steps=offline_steps, offline_evaluation=offline_evaluation, notes=notes)
    return {**record, **extra}


def _fit_online(d3rlpy: Any, learner: Any, ds: OfflineDataset, settings: Mapping[str, Any], offline: Any, seed: int,
                out: Path, logs: Any, online_steps: int, offline_ratio: float, updates_per_step: int) -> None:
    """``fit_online`` on the dataset's environment, ``offline_ratio`` of each batch from ``offline``."""
    env = make_traffic_env(**settings)
    try:
        ds.check_compatible(env)
        env.reset(seed=seed)  # fit_online resets without a seed: the episodes continue this generator
        env.action_space.seed(seed)
        env = Monitor(env, str(out / "online"), info_keywords=("collision",))
        online = d3rlpy.dataset.create_infinite_replay_buffer(env=env)
        buffer = _mixed_buffer(d3rlpy, online, offline, float(offline_ratio))
        learner.fit_online(env, buffer, n_steps=online_steps, n_steps_per_epoch=online_steps,
                           n_updates=updates_per_step, experiment_name="online", with_timestamp=False,
                           logger_adapter=logs, show_progress=False)
    finally:
        env.close()
