"""Offline data of ``MixedTraffic-v0``: the SUMO behaviour policy, dataset collection, and the
environment every offline-to-online stage rebuilds from a dataset's metadata
(:func:`make_traffic_env`: with the driving-style context c_t when the dataset records a
``style_classifier``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_ua2c import offline
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import Episode, OfflineDataset, load_dataset, write_dataset

#: UA2C arguments for ``MixedTraffic-v0`` (the lane change, action dim 1, is categorical).
TRAFFIC_DEFAULTS: dict[str, Any] = {"discrete_action_dims": {1: [-1.0, 0.0, 1.0]}}


#: ``BehaviourConfig.driver_style`` values (the middle three are ``envs.STYLES``).
DRIVER_STYLES = ("default", "conservative", "neutral", "aggressive", "mixed")


@dataclass(frozen=True)
class BehaviourConfig:
    """Behaviour policy of an offline collection run on ``MixedTraffic-v0`` (human-like driving).

    Per episode, SUMO's own car-following and lane-change models drive the AV with probability
    ``sumo_fraction``; the recorded action is the one SUMO actually performed
    (``info["applied_action"]``). To widen state coverage, at each step of a SUMO-driven episode a
    takeover starts with probability ``perturb_prob``: for ``perturb_steps`` steps the AV holds the
    last performed acceleration plus Gaussian noise of standard deviation ``accel_noise`` [m/s²]
    (drawn once per takeover), with a random lane change at its first step with probability
    ``lane_change_prob``. Long takeovers are lapses of attention: the AV keeps accelerating towards
    a slower leader or the end of the acceleration lane and SUMO's driver takes back control late,
    sometimes too late, so the data also hold the near-misses and collisions a value function
    needs to learn what unsafe chunks cost. The remaining episodes use a random policy
    (uniform acceleration, lane change with probability ``lane_change_prob`` per step).

    :param sumo_fraction: fraction of episodes driven by SUMO's driver model, in [0, 1]
    :param perturb_prob: per-step probability that a takeover starts in SUMO episodes, in [0, 1]
    :param accel_noise: standard deviation of a takeover's acceleration offset [m/s²], >= 0
    :param perturb_steps: length of a takeover in environment steps, >= 1
    :param lane_change_prob: per-step probability of a random lane change (takeovers, random episodes)
    :param driver_style: parameters of SUMO's driver model for the AV: ``"default"`` (the AV's own
        moderate IDM type), an HDV style (``"conservative"``, ``"neutral"``, ``"aggressive"``) or
        ``"mixed"`` (one of the three drawn per episode)
    """

    sumo_fraction: float = 1.0
    perturb_prob: float = 0.03
    accel_noise: float = 2.5
    perturb_steps: int = 15
    lane_change_prob: float = 0.02
    driver_style: str = "mixed"

    def __post_init__(self) -> None:
        for name in ("sumo_fraction", "perturb_prob", "lane_change_prob"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                raise ValueError(f"BehaviourConfig.{name} must be a number in [0, 1], got {value!r}")
        if isinstance(self.accel_noise, bool) or not isinstance(self.accel_noise, int | float) or not (
            np.isfinite(self.accel_noise) and self.accel_noise >= 0
        ):
            raise ValueError(f"BehaviourConfig.accel_noise must be a finite number >= 0, got {self.accel_noise!r}")
        check_int("BehaviourConfig.perturb_steps", self.perturb_steps)
        if self.driver_style not in DRIVER_STYLES:
            raise ValueError(f"BehaviourConfig.driver_style must be one of {DRIVER_STYLES}, got {self.driver_style!r}")

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> BehaviourConfig:
        """Build from a mapping; an unknown key raises ``ValueError`` naming it."""
        unknown = set(values) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown BehaviourConfig key(s) {sorted(unknown)}; valid: {sorted(cls.__dataclass_fields__)}")
        return cls(**values)


def make_traffic_env(
    env_id: str = "MixedTraffic-v0",
    env_kwargs: dict[str, Any] | None = None,
    style_classifier: str | os.PathLike | None = None,
) -> gym.Env:
    """The environment a traffic dataset's metadata names (:func:`sb3_ua2c.pipeline.env_settings`):
    the algorithm's generic :func:`sb3_ua2c.offline.make_env`, plus the driving-style context c_t
    (Eq. 6) when the dataset records a ``style_classifier``. Pass it as ``make_env=`` to
    :func:`sb3_ua2c.pipeline.pretrain` / :func:`~sb3_ua2c.pipeline.finetune`.

    :param env_id: a registered gymnasium id (``import envs`` registers ``MixedTraffic-v0``)
    :param env_kwargs: keyword arguments of the environment
    :param style_classifier: path of a saved :class:`~envs.style.DrivingStyleClassifier`, or
        ``"default"`` for the packaged one; when given, observations carry the driving-style
        context c_t (Eq. 6) through :class:`~envs.wrappers.DrivingStyleContext`
    """
    env = offline.make_env(env_id, env_kwargs)
    if style_classifier is not None:
        from envs.wrappers import DrivingStyleContext

        env = DrivingStyleContext(env, classifier=None if style_classifier == "default" else style_classifier)
    return env


class BehaviourDriver:
    """The behaviour policy of a :class:`BehaviourConfig` driving a ``MixedTraffic-v0`` (possibly
    wrapped), one episode at a time: :meth:`reset` starts an episode (SUMO's driver or the random
    policy, and the driver style), :meth:`step` makes one step (takeovers, lane changes) and returns
    the action the AV performed (``info["applied_action"]``, clipped to the action space).

    :param env: the environment (its unwrapped env must offer ``set_ego_controller``)
    :param behaviour: the behaviour policy
    :param rng: the behaviour's own randomness
    """

    def __init__(self, env: gym.Env, behaviour: BehaviourConfig, rng: np.random.Generator) -> None:
        if not hasattr(env.unwrapped, "set_ego_controller"):
            raise ValueError(
                f"the behaviour policy needs a MixedTraffic env (with set_ego_controller), got {type(env.unwrapped).__name__}"
            )
        self.env, self.behaviour, self.rng = env, behaviour, rng
        self.low = env.action_space.low.astype(np.float64)
        self.high = env.action_space.high.astype(np.float64)
        self.sumo_driven = False
        self.last_accel = 0.0
        self.takeover_left, self.takeover_accel = 0, 0.0  # steps left in the current takeover, its acceleration

    def reset(self, seed: int) -> tuple[Any, dict[str, Any]]:
        """Start an episode on the scenario of ``seed``: ``env.reset``'s observation and info."""
        b, base = self.behaviour, self.env.unwrapped
        self.sumo_driven = bool(self.rng.random() < b.sumo_fraction)
        obs, info = self.env.reset(seed=seed, options={"ego_controller": "sumo" if self.sumo_driven else "agent"})
        style = b.driver_style
        if style == "mixed":
            style = DRIVER_STYLES[1 + int(self.rng.integers(3))]
        if self.sumo_driven and style != "default":
            base.set_ego_driver_style(style)
        self.last_accel, self.takeover_left, self.takeover_accel = 0.0, 0, 0.0
        return obs, info

    def step(self) -> tuple[Any, float, bool, bool, dict[str, Any], np.ndarray]:
        """One step: ``env.step``'s five values and the performed action, shape ``(action_dim,)``."""
        b, rng = self.behaviour, self.rng
        lane_change = float(rng.choice((-1.0, 1.0))) if rng.random() < b.lane_change_prob else 0.0
        if self.sumo_driven:
            starts = bool(rng.random() < b.perturb_prob)
            noise = float(rng.standard_normal())  # drawn every step: the same stream for any perturb_steps
            if self.takeover_left == 0 and starts:
                self.takeover_left = b.perturb_steps
                self.takeover_accel = self.last_accel + b.accel_noise * noise
            else:
                lane_change = 0.0  # random lane changes only at the first step of a takeover
            self.env.unwrapped.set_ego_controller("agent" if self.takeover_left > 0 else "sumo")
            action = np.array([self.takeover_accel, lane_change])
            self.takeover_left = max(self.takeover_left - 1, 0)
        else:
            action = np.array([rng.uniform(self.low[0], self.high[0]), lane_change])
        action = np.clip(action, self.low, self.high).astype(self.env.action_space.dtype)
        obs, reward, terminated, truncated, info = self.env.step(action)
        performed = np.asarray(info["applied_action"], dtype=np.float64)
        self.last_accel = float(performed[0])
        return obs, float(reward), bool(terminated), bool(truncated), info, np.clip(performed, self.low, self.high)


def collect_episodes(
    env: gym.Env,
    n_episodes: int,
    behaviour: BehaviourConfig | None = None,
    seed: int = 0,
    progress_bar: bool = False,
) -> list[Episode]:
    """Drive ``env`` (a ``MixedTraffic-v0``, possibly wrapped) with the behaviour policy.

    Episode ``i`` is reset with seed ``seed + i``; the behaviour's own randomness comes from a
    generator seeded with ``seed``, so the same arguments give the same episodes.

    :param env: the environment (its unwrapped env must offer ``set_ego_controller``)
    :param n_episodes: number of episodes, >= 1
    :param behaviour: the behaviour policy (default :class:`BehaviourConfig`)
    :param seed: base seed
    :param progress_bar: show a tqdm progress bar
    :return: the episodes, actions in the environment's units
    """
    check_int("n_episodes", n_episodes)
    driver = BehaviourDriver(env, behaviour or BehaviourConfig(), np.random.default_rng(seed))
    episodes = []
    iterator = range(n_episodes)
    if progress_bar:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc="collect", unit="episode")
    for i in iterator:
        obs, _ = driver.reset(seed + i)
        observations, actions, rewards, terminations, truncations = [obs], [], [], [], []
        done = False
        while not done:
            obs, reward, terminated, truncated, _, performed = driver.step()
            observations.append(obs)
            actions.append(performed)
            rewards.append(reward)
            terminations.append(terminated)
            truncations.append(truncated)
            done = terminated or truncated
        episodes.append(
            Episode(
                observations=np.asarray(observations, dtype=env.observation_space.dtype),
                actions=np.asarray(actions, dtype=env.action_space.dtype),
                rewards=np.asarray(rewards),
                terminations=np.asarray(terminations),
                truncations=np.asarray(truncations),
                seed=seed + i,
            )
        )
    return episodes


def collect_dataset(
    path: str | os.PathLike,
    n_episodes: int,
    env_id: str = "MixedTraffic-v0",
    env_kwargs: dict[str, Any] | None = None,
    style_classifier: str | None = None,
    behaviour: BehaviourConfig | None = None,
    seed: int = 0,
    progress_bar: bool = False,
    overwrite: bool = False,
) -> OfflineDataset:
    """Collect ``n_episodes`` with the behaviour policy and store them as a local Minari dataset.

    The metadata records everything needed to rebuild the same environment (``env_id``,
    ``env_kwargs``, ``style_classifier``), the behaviour policy and the seed.

    :return: the dataset, loaded back from disk
    """
    behaviour = behaviour or BehaviourConfig()
    env = make_traffic_env(env_id, env_kwargs, style_classifier)
    try:
        episodes = collect_episodes(env, n_episodes, behaviour, seed=seed, progress_bar=progress_bar)
        metadata = {
            "env_id": env_id,
            "env_kwargs": dict(env_kwargs or {}),
            "style_classifier": None if style_classifier is None else str(style_classifier),
            "behaviour": "sumo-driver+perturbation/random",
            "behaviour_config": {k: getattr(behaviour, k) for k in behaviour.__dataclass_fields__},
            "seed": seed,
            "n_episodes": n_episodes,
            "total_steps": int(sum(len(ep) for ep in episodes)),
            "mean_return": float(np.mean([ep.rewards.sum() for ep in episodes])),
        }
        write_dataset(
            episodes, path, env.observation_space, env.action_space, env=env,
            metadata=metadata, overwrite=overwrite,
        )
    finally:
        env.close()
    return load_dataset(path)
