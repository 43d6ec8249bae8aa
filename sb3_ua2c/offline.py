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
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

METADATA_FILE = "ua2c_metadata.json"


class OfflineDatasetError(ValueError):
    """A dataset is missing, corrupt, or does not match the environment it is used with."""


@dataclass(frozen=True)
class Episode:
    """One logged episode: what a dataset holds and what :meth:`UA2C.add_offline_episodes
    <sb3_ua2c.ua2c.UA2C.add_offline_episodes>` takes (actions in the env's units, or in SB3's normalised
    [-1, 1] with ``actions_normalized=True``; the replay buffer stores them normalised).

    :param observations: ``(T + 1, *obs_shape)``: o_0 .. o_T (the last one is the final observation);
        ``(T, *obs_shape)`` when ``next_observations`` is given
    :param actions: ``(T, *act_shape)``: a_0 .. a_{T-1} as actually executed
    :param rewards: ``(T,)``
    :param terminations: ``(T,)`` bool: the MDP ended at this step (no bootstrap after it)
    :param truncations: ``(T,)`` bool: the episode was cut at this step (time limit: bootstrap)
    :param next_observations: ``(T, *obs_shape)``: o_1 .. o_T, or ``None`` (taken from ``observations``)
    :param seed: the reset seed of the episode, if known
    :param infos: per-step infos to store with the dataset
    :raises OfflineDatasetError: (a ``ValueError``) on an empty episode, rows that do not fit ``T``, or
        NaN or inf values, naming the field
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    next_observations: np.ndarray | None = None
    seed: int | None = None
    infos: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.actions)
        if n == 0:
            raise OfflineDatasetError("an episode must contain at least one step")
        if self.next_observations is None and len(self.observations) != n + 1:
            raise OfflineDatasetError(
                f"observations must have T+1={n + 1} rows for T={n} actions when next_observations is "
                f"omitted, got {len(self.observations)}"
            )
        rows = ("rewards", "terminations", "truncations")
        if self.next_observations is not None:
            rows = ("observations", "next_observations", *rows)
        for name in rows:
            if len(getattr(self, name)) != n:
                raise OfflineDatasetError(f"{name} must have T={n} rows, got {len(getattr(self, name))}")
        for name in ("observations", "actions", "rewards", "next_observations"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise OfflineDatasetError(f"episode {name} contain NaN or inf")

    @classmethod
    def coerce(cls, episode: Episode | Mapping[str, Any]) -> Episode:
        """An :class:`Episode` as it is, or one built from a mapping with its field names (an unknown key
        raises ``ValueError`` naming it)."""
        if isinstance(episode, cls):
            return episode
        if not isinstance(episode, Mapping):
            raise ValueError(f"an offline episode must be an Episode or a mapping, got {type(episode).__name__}")
        unknown = sorted(set(episode) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(
                f"unknown offline episode key(s) {unknown}; allowed: {sorted(cls.__dataclass_fields__)}"
            )
        return cls(**episode)

    def __len__(self) -> int:
        return len(self.actions)


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


def make_env(env_id: str, env_kwargs: dict[str, Any] | None = None, **settings: Any) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)``: the environment a dataset's metadata names.

    ``env_id`` may name the module that registers it (``"package.module:Env-v0"``, gymnasium's
    convention), so that no import is needed first. A dataset written by an application package
    may record further settings (e.g. ``style_classifier`` of ``envs``): this generic maker
    builds only datasets whose further settings are all ``None``; pass the application's own maker
    (``make_env=envs.make_traffic_env``) to the stages of :mod:`sb3_ua2c.pipeline` otherwise.

    :param env_id: a registered gymnasium id
    :param env_kwargs: keyword arguments of the environment
    :param settings: further recorded settings; every one must be ``None`` here
    """
    given = sorted(key for key, value in settings.items() if value is not None)
    if given:
        raise ValueError(
            f"the dataset records the setting(s) {given}, which the generic make_env cannot apply: "
            f"pass the make_env of the package that wrote the dataset (e.g. envs.make_traffic_env)"
        )
    return gym.make(env_id, **(env_kwargs or {}))

