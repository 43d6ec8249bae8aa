"""Offline-to-online stages: Phase 1 pre-training and Phase 2 online adaptation, for any environment.

Every stage rebuilds the environment from the dataset's metadata (``env_id``, ``env_kwargs``,
``style_classifier``), so the data, the checkpoint and the online env always share their spaces.
Checkpoints are standard SB3 ``.zip`` files (``UA2C.load`` opens them), written to a temporary
file and renamed, so an interrupted run never leaves a half-written checkpoint.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor

from sb3_ua2c.offline import (
    OfflineDataset,
    OfflineDatasetError,
    check_spaces_match,
    load_dataset,
    make_env,
)
from sb3_ua2c.ua2c import UA2C

EnvMaker = Callable[..., gym.Env]


def env_settings(dataset: OfflineDataset) -> dict[str, Any]:
    """``make_env`` arguments recorded in a dataset's metadata."""
    meta = dataset.metadata
    if "env_id" not in meta:
        raise OfflineDatasetError(f"dataset {dataset.path} records no env_id in its metadata")
    return {
        "env_id": meta["env_id"],
        "env_kwargs": dict(meta.get("env_kwargs") or {}),
        "style_classifier": meta.get("style_classifier"),
    }


def save_atomic(model: UA2C, path: str | os.PathLike) -> Path:
    """Save ``model`` to ``path`` (``.zip`` added if missing) through a temporary file and a rename."""
    path = Path(path)
    if path.suffix != ".zip":
        path = path.with_suffix(path.suffix + ".zip") if path.suffix else path.with_suffix(".zip")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".zip", dir=path.parent)
    os.close(fd)
    try:
        model.save(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def load_checkpoint(path: str | os.PathLike, env: Any, **overrides: Any) -> UA2C:
    """``UA2C.load`` with a readable error for a missing or foreign checkpoint and a space check."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        model = UA2C.load(path, env=None, device="cpu", **overrides)
    except Exception as exc:  # zipfile / pickle errors of a damaged or foreign file
        raise ValueError(f"checkpoint {path} is not a loadable UA2C .zip: {exc}") from exc
    check_spaces_match(model.observation_space, model.action_space, env, what=f"checkpoint {path}")
    model.set_env(env)
    return model


def pretrain(
    dataset: str | os.PathLike | OfflineDataset,
    out: str | os.PathLike,
    n_gradient_steps: int,
    seed: int = 0,
    algo_kwargs: dict[str, Any] | None = None,
    progress_bar: bool = False,
    verbose: int = 0,
    make_env: EnvMaker = make_env,
) -> Path:
    """Phase 1: pre-train UA2C from an offline dataset alone (Eq. 2, Eq. 3 with the Eq. 4 target).

    The chunk length is fixed (``chunk_size``); ``chunk_size=1`` gives the one-step baseline on
    the same data and code path.

    :param dataset: dataset directory or a loaded :class:`~sb3_ua2c.offline.OfflineDataset`
    :param out: checkpoint path (``.zip``)
    :param n_gradient_steps: gradient steps
    :param seed: seed of the networks and minibatch sampling
    :param algo_kwargs: UA2C constructor arguments
    :param make_env: builds the environment from the dataset's settings (:func:`env_settings`);
        :func:`sb3_ua2c.offline.make_env` by default, ``envs.make_traffic_env`` for ``MixedTraffic-v0`` data
    :return: the checkpoint path
    """
    ds = dataset if isinstance(dataset, OfflineDataset) else load_dataset(dataset)
    settings = env_settings(ds)
    kwargs = dict(algo_kwargs or {})
    env = make_env(**settings)
    try:
        ds.check_compatible(env)
        model = UA2C("MlpPolicy", env, seed=seed, verbose=verbose, device="cpu", **kwargs)
        model.add_offline_episodes(ds.episodes)
        _pretrain_with_progress(model, n_gradient_steps, progress_bar)
        return save_atomic(model, out)
    finally:
        env.close()


def _pretrain_with_progress(model: UA2C, n_gradient_steps: int, progress_bar: bool) -> None:
    if not progress_bar:
        model.pretrain(n_gradient_steps)
        return
    from tqdm.auto import tqdm

    chunk = max(1, n_gradient_steps // 50)
    with tqdm(total=n_gradient_steps, desc="pretrain", unit="step") as bar:
        done = 0
        while done < n_gradient_steps:
            steps = min(chunk, n_gradient_steps - done)
            model.pretrain(steps, log_interval=steps)
            done += steps
            bar.update(steps)


def finetune(
    checkpoint: str | os.PathLike,
    out: str | os.PathLike,
    total_timesteps: int,
    dataset: str | os.PathLike | OfflineDataset | None = None,
    env_settings_: dict[str, Any] | None = None,
    offline_ratio: float | None = None,
    entropy_threshold: float | str | None = None,
    seed: int = 0,
    progress_bar: bool = False,
    callback: Any = None,
    algo_overrides: dict[str, Any] | None = None,
    monitor_file: str | os.PathLike | None = None,
    make_env: EnvMaker = make_env,
) -> Path:
    """Phase 2: online adaptation from a pre-trained checkpoint with adaptive execution (Eq. 7, 8).

    The first update starts exactly from the loaded weights; learning starts at once
    (``learning_starts=0``: the pre-trained policy acts from the first step). Offline episodes of
    ``dataset`` stay in the replay buffer and make up ``offline_ratio`` of each minibatch.

    :param checkpoint: pre-trained ``.zip``
    :param out: fine-tuned checkpoint path
    :param total_timesteps: online environment steps
    :param dataset: offline data kept in the replay buffer (its metadata also defines the env)
    :param env_settings_: ``make_env`` arguments when no dataset is given
    :param offline_ratio: override the checkpoint's offline mixing ratio
    :param entropy_threshold: override δ of Eq. 7: a float (``inf`` = fixed chunk execution) or
        ``"auto"`` (set from recent plans, as ``UA2C(entropy_threshold="auto")``); ``None`` keeps the
        checkpoint's
    :param seed: seed of the online phase
    :param callback: SB3 callback(s) passed to ``learn``
    :param algo_overrides: further attributes to override on load (e.g. ``{"gradient_steps": 1}``);
        ``n_elite`` sets the policy's elite mean (``UA2C.load``: rollouts and the saved checkpoint act
        by it); shape-changing arguments (``chunk_size``, ``history_len``,
        ``policy_kwargs``) are refused
    :param monitor_file: write SB3's ``Monitor`` log of the online episodes (return, length, wall
        time and ``collision``) to this CSV file (``.monitor.csv`` is appended unless present); read
        it back with :func:`read_monitor`
    :param make_env: builds the environment from the settings (see :func:`pretrain`)
    :return: the fine-tuned checkpoint path
    """
    ds = None
    if dataset is not None:
        ds = dataset if isinstance(dataset, OfflineDataset) else load_dataset(dataset)
    shape_args = {"chunk_size", "history_len", "policy_kwargs"} & set(algo_overrides or {})
    if shape_args:
        raise ValueError(f"algo_overrides cannot change the network shapes of a checkpoint: {sorted(shape_args)}")
    if ds is None and env_settings_ is None:
        raise ValueError("finetune needs a dataset or env_settings_ to build the environment")
    settings = env_settings(ds) if ds is not None else dict(env_settings_)
    overrides: dict[str, Any] = {"learning_starts": 0, **(algo_overrides or {})}
    if offline_ratio is not None:
        overrides["offline_ratio"] = offline_ratio
    if entropy_threshold is not None:
        overrides["entropy_threshold"] = entropy_threshold
    env = make_env(**settings)
    if monitor_file is not None:
        env = Monitor(env, str(monitor_file), info_keywords=("collision",))
    try:
        model = load_checkpoint(checkpoint, env, **overrides)
        model.set_random_seed(seed)
        if ds is not None:
            ds.check_compatible(env)
            model.add_offline_episodes(ds.episodes)
        model.learn(total_timesteps, callback=callback, progress_bar=progress_bar, reset_num_timesteps=True)
        return save_atomic(model, out)
    finally:
        env.close()


def read_monitor(path: str | os.PathLike) -> list[dict[str, float]]:
    """The episodes of a ``Monitor`` CSV log (see ``finetune(monitor_file=...)``), in order.

    :param path: the log (``.monitor.csv`` is appended unless present)
    :return: one dict per episode with the float columns ``r`` (return), ``l`` (length), ``t`` (wall
        time) and any ``info_keywords`` (``collision`` is 1.0 / 0.0)
    """
    path = Path(path)
    if not path.name.endswith(Monitor.EXT):
        path = path.with_name(f"{path.name}.{Monitor.EXT}")
    with path.open(newline="") as f:
        header = f.readline()
        if not header.startswith("#"):
            raise ValueError(f"{path} is not a Monitor log (no '#' header line)")
        rows = list(csv.DictReader(f))
    return [{key: float(value in ("True", "1", "1.0")) if value in ("True", "False") else float(value)
             for key, value in row.items()} for row in rows]


def write_json(path: str | os.PathLike, payload: Any) -> Path:
    """Write JSON atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True, default=_json_default))
    os.replace(tmp, path)
    return path


def _json_default(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


__all__ = [
    "OfflineDatasetError", "env_settings", "finetune", "load_checkpoint", "pretrain", "read_monitor", "save_atomic",
    "write_json",
]
