"""Offline driving datasets: collect episodes, store them as local Minari datasets, load them back.

A dataset is a plain local Minari dataset (HDF5 storage, no hub involved). It lives in a directory
``<root>/<namespace>/<name>-v<N>/`` with Minari's ``data/`` folder inside, plus our own
``ua2c_metadata.json`` (scenario config, behaviour policy, seeds). Datasets are written to a
temporary directory next to the destination and renamed into place at the end, so an interrupted
collection never leaves a half-written dataset behind.

The conversion of episodes into UA2C chunk transitions (histories, k-step chunks, discounted
returns, bootstrap masks; Eq. 4) is done by :meth:`sb3_ua2c.buffers.ChunkReplayBuffer.add_offline_episodes`,
which keeps one code path for offline windows and online plans.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_ua2c.checks import check_int

METADATA_FILE = "ua2c_metadata.json"


class OfflineDatasetError(ValueError):
    """A dataset is missing, corrupt, or does not match the environment it is used with."""


@dataclass(frozen=True)
class Episode:
    """One logged episode, arrays in the environment's own units.

    :param observations: ``(T + 1, *obs_shape)``: o_0 .. o_T (the last one is the final observation)
    :param actions: ``(T, *act_shape)``: a_0 .. a_{T-1} as actually executed
    :param rewards: ``(T,)``
    :param terminations: ``(T,)`` bool: the MDP ended at this step (no bootstrap after it)
    :param truncations: ``(T,)`` bool: the episode was cut at this step (time limit: bootstrap)
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    seed: int | None = None
    infos: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.rewards)
        if n == 0:
            raise OfflineDatasetError("an episode must contain at least one step")
        if len(self.observations) != n + 1:
            raise OfflineDatasetError(
                f"observations must have T+1={n + 1} rows for T={n} rewards, got {len(self.observations)}"
            )
        for name in ("actions", "terminations", "truncations"):
            if len(getattr(self, name)) != n:
                raise OfflineDatasetError(f"{name} must have T={n} rows, got {len(getattr(self, name))}")
        for name in ("observations", "actions", "rewards"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise OfflineDatasetError(f"episode {name} contain NaN or inf")

    def __len__(self) -> int:
        return len(self.rewards)


@dataclass
class OfflineDataset:
    """A loaded offline dataset: its episodes, spaces and metadata.

    :param path: the dataset directory (the one holding ``data/``)
    :param episodes: the episodes, in order
    :param observation_space: observation space recorded with the data
    :param action_space: action space recorded with the data
    :param metadata: ``ua2c_metadata.json`` (scenario config, behaviour policy, seed, ...)
    """

    path: Path
    episodes: list[Episode]
    observation_space: gym.Space
    action_space: gym.Space
    metadata: dict[str, Any]

    @property
    def total_steps(self) -> int:
        return sum(len(ep) for ep in self.episodes)

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self) -> Iterator[Episode]:
        return iter(self.episodes)

    def check_compatible(self, env: gym.Env | Any) -> None:
        """Raise :class:`OfflineDatasetError` unless ``env`` (gym env or VecEnv) has this dataset's spaces."""
        check_spaces_match(self.observation_space, self.action_space, env, what=f"dataset {self.path}")


def check_spaces_match(observation_space: gym.Space, action_space: gym.Space, env: Any, what: str) -> None:
    """Compare recorded spaces with an environment's, raising a readable error on mismatch."""
    for name, recorded in (("observation_space", observation_space), ("action_space", action_space)):
        actual = getattr(env, name)
        if not _same_space(recorded, actual):
            raise OfflineDatasetError(
                f"{what} has {name} {recorded} but the environment has {actual}: "
                "collect the data with the same environment configuration (and wrappers)"
            )


def _same_space(a: gym.Space, b: gym.Space) -> bool:
    if type(a) is not type(b) or a.shape != b.shape:
        return False
    if isinstance(a, gym.spaces.Box):
        return bool(np.allclose(a.low, b.low) and np.allclose(a.high, b.high))
    return a == b


def dataset_path(root: str | os.PathLike, dataset_id: str) -> Path:
    """Directory of dataset ``dataset_id`` (``namespace/name-vN``) under ``root``."""
    if not dataset_id or dataset_id.startswith("/") or ".." in dataset_id.split("/"):
        raise ValueError(f"dataset_id must be a relative Minari id like 'mixedtraffic/sumo-v0', got {dataset_id!r}")
    return Path(root) / dataset_id


def write_dataset(
    episodes: list[Episode],
    path: str | os.PathLike,
    observation_space: gym.Space,
    action_space: gym.Space,
    env: gym.Env | None = None,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write episodes as a Minari dataset at ``path`` atomically (temporary directory, then rename).

    :param episodes: the episodes to store
    :param path: destination directory (it will hold Minari's ``data/`` and our metadata file)
    :param observation_space: the environment's observation space
    :param action_space: the environment's action space
    :param env: the (open) environment the data came from; Minari stores its spec so it can be
        recreated (pass the object, not an id: a second SUMO simulation cannot open in this process)
    :param metadata: JSON-serialisable extra metadata (scenario config, behaviour policy, seed)
    :param overwrite: replace an existing dataset at ``path``
    :return: ``path``
    """
    import minari
    from minari.data_collector.episode_buffer import EpisodeBuffer

    if not episodes:
        raise ValueError("episodes must not be empty")
    path = Path(path).absolute()  # Minari resolves its root from an environment variable: no relative paths
    if path.exists() and not overwrite:
        raise FileExistsError(f"dataset {path} already exists (pass overwrite=True to replace it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    buffers = [
        EpisodeBuffer(
            id=i,
            seed=ep.seed,
            observations=np.asarray(ep.observations, dtype=observation_space.dtype),
            actions=np.asarray(ep.actions, dtype=action_space.dtype),
            rewards=[float(r) for r in ep.rewards],
            terminations=[bool(t) for t in ep.terminations],
            truncations=[bool(t) for t in ep.truncations],
            infos={k: np.asarray(v) for k, v in ep.infos.items()} or None,
        )
        for i, ep in enumerate(episodes)
    ]
    metadata = dict(metadata or {})
    tmp_root = Path(tempfile.mkdtemp(prefix=".tmp-dataset-", dir=path.parent))
    old_root = os.environ.get("MINARI_DATASETS_PATH")
    try:
        os.environ["MINARI_DATASETS_PATH"] = str(tmp_root)
        tmp_id = f"ua2c/tmp{uuid.uuid4().hex[:8]}-v0"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # Minari's author / permalink reminders
            minari.create_dataset_from_buffers(
                dataset_id=tmp_id,
                buffer=buffers,
                env=env,
                algorithm_name=str(metadata.get("behaviour", "unknown")),
                description=json.dumps(metadata, sort_keys=True, default=str),
                observation_space=observation_space,
                action_space=action_space,
                data_format="hdf5",
            )
        built = tmp_root / tmp_id
        with open(built / METADATA_FILE, "w") as f:
            json.dump(metadata, f, indent=2, sort_keys=True, default=str)
        if path.exists():
            shutil.rmtree(path)
        os.replace(built, path)
    finally:
        if old_root is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old_root
        shutil.rmtree(tmp_root, ignore_errors=True)
    return path


def load_dataset(path: str | os.PathLike) -> OfflineDataset:
    """Load a dataset written by :func:`write_dataset` (or any local Minari dataset directory).

    :param path: the dataset directory (the one that holds ``data/``)
    :raises OfflineDatasetError: when the directory is missing, not a Minari dataset, or unreadable
    """
    from minari import MinariDataset

    path = Path(path)
    if not (path / "data").is_dir():
        raise OfflineDatasetError(f"no dataset at {path} (expected a Minari dataset directory with data/ inside)")
    try:
        ds = MinariDataset(path / "data")
        episodes = [
            Episode(
                observations=np.asarray(e.observations),
                actions=np.asarray(e.actions),
                rewards=np.asarray(e.rewards, dtype=np.float64),
                terminations=np.asarray(e.terminations, dtype=bool),
                truncations=np.asarray(e.truncations, dtype=bool),
                seed=None,
            )
            for e in ds.iterate_episodes()
        ]
        observation_space, action_space = ds.observation_space, ds.action_space
    except OfflineDatasetError:
        raise
    except Exception as exc:  # h5py / json errors on a damaged file
        raise OfflineDatasetError(f"dataset {path} is corrupt or unreadable: {exc}") from exc
    if not episodes:
        raise OfflineDatasetError(f"dataset {path} holds no episodes")
    metadata: dict[str, Any] = {}
    if (path / METADATA_FILE).is_file():
        try:
            metadata = json.loads((path / METADATA_FILE).read_text())
        except json.JSONDecodeError as exc:
            raise OfflineDatasetError(f"dataset {path}: {METADATA_FILE} is corrupt: {exc}") from exc
    return OfflineDataset(path, episodes, observation_space, action_space, metadata)


BehaviourPolicy = Callable[[np.ndarray, dict[str, Any], np.random.Generator], np.ndarray | None]


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


def make_env(
    env_id: str = "MixedTraffic-v0",
    env_kwargs: dict[str, Any] | None = None,
    style_classifier: str | os.PathLike | None = None,
) -> gym.Env:
    """Create the environment used by every offline-to-online stage (same spaces everywhere).

    :param env_id: a registered gymnasium id (``import envs`` registers ``MixedTraffic-v0``)
    :param env_kwargs: keyword arguments of the environment
    :param style_classifier: path of a saved :class:`~sb3_ua2c.style.DrivingStyleClassifier`, or
        ``"default"`` for the packaged one; when given, observations carry the driving-style
        context c_t (Eq. 6) through :class:`~sb3_ua2c.wrappers.DrivingStyleContext`
    """
    import envs  # noqa: F401  (registers MixedTraffic-v0)

    env = gym.make(env_id, **(env_kwargs or {}))
    if style_classifier is not None:
        from sb3_ua2c.wrappers import DrivingStyleContext

        env = DrivingStyleContext(env, classifier=None if style_classifier == "default" else style_classifier)
    return env


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
    behaviour = behaviour or BehaviourConfig()
    base = env.unwrapped
    if not hasattr(base, "set_ego_controller"):
        raise ValueError(f"collect_episodes needs a MixedTraffic env (with set_ego_controller), got {type(base).__name__}")
    low, high = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    rng = np.random.default_rng(seed)
    episodes = []
    iterator = range(n_episodes)
    if progress_bar:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc="collect", unit="episode")
    for i in iterator:
        sumo_driven = bool(rng.random() < behaviour.sumo_fraction)
        obs, info = env.reset(seed=seed + i, options={"ego_controller": "sumo" if sumo_driven else "agent"})
        style = behaviour.driver_style
        if style == "mixed":
            style = DRIVER_STYLES[1 + int(rng.integers(3))]
        if sumo_driven and style != "default":
            base.set_ego_driver_style(style)
        observations, actions, rewards, terminations, truncations = [obs], [], [], [], []
        last_accel = 0.0
        takeover_left, takeover_accel = 0, 0.0  # steps left in the current takeover, its acceleration
        done = False
        while not done:
            lane_change = float(rng.choice((-1.0, 1.0))) if rng.random() < behaviour.lane_change_prob else 0.0
            if sumo_driven:
                starts = bool(rng.random() < behaviour.perturb_prob)
                noise = float(rng.standard_normal())  # drawn every step: the same stream for any perturb_steps
                if takeover_left == 0 and starts:
                    takeover_left = behaviour.perturb_steps
                    takeover_accel = last_accel + behaviour.accel_noise * noise
                else:
                    lane_change = 0.0  # random lane changes only at the first step of a takeover
                base.set_ego_controller("agent" if takeover_left > 0 else "sumo")
                action = np.array([takeover_accel, lane_change])
                takeover_left = max(takeover_left - 1, 0)
            else:
                action = np.array([rng.uniform(low[0], high[0]), lane_change])
            action = np.clip(action, low, high).astype(env.action_space.dtype)
            obs, reward, terminated, truncated, info = env.step(action)
            performed = np.asarray(info["applied_action"], dtype=np.float64)
            last_accel = float(performed[0])
            observations.append(obs)
            actions.append(np.clip(performed, low, high))
            rewards.append(float(reward))
            terminations.append(bool(terminated))
            truncations.append(bool(truncated))
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
    env = make_env(env_id, env_kwargs, style_classifier)
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
