"""Offline-to-online stages: Phase 1 pre-training, Phase 2 online adaptation, evaluation.

Every stage rebuilds the environment from the dataset's metadata (``env_id``, ``env_kwargs``,
``style_classifier``), so the data, the checkpoint and the online env always share their spaces.
Checkpoints are standard SB3 ``.zip`` files (``UA2C.load`` opens them), written to a temporary
file and renamed, so an interrupted run never leaves a half-written checkpoint.
"""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.monitor import Monitor

from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import (
    OfflineDataset,
    OfflineDatasetError,
    check_spaces_match,
    load_dataset,
    make_env,
)
from sb3_ua2c.ua2c import UA2C

#: UA2C arguments for ``MixedTraffic-v0`` (the lane change, action dim 1, is categorical).
TRAFFIC_DEFAULTS: dict[str, Any] = {"discrete_action_dims": {1: [-1.0, 0.0, 1.0]}}


def env_settings(dataset: OfflineDataset) -> dict[str, Any]:
    """``make_env`` arguments recorded in a dataset's metadata."""
    meta = dataset.metadata
    return {
        "env_id": meta.get("env_id", "MixedTraffic-v0"),
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
) -> Path:
    """Phase 1: pre-train UA2C from an offline dataset alone (Eq. 2, Eq. 3 with the Eq. 4 target).

    The chunk length is fixed (``chunk_size``); ``chunk_size=1`` gives the one-step baseline on
    the same data and code path.

    :param dataset: dataset directory or a loaded :class:`~sb3_ua2c.offline.OfflineDataset`
    :param out: checkpoint path (``.zip``)
    :param n_gradient_steps: gradient steps
    :param seed: seed of the networks and minibatch sampling
    :param algo_kwargs: UA2C constructor arguments (defaults: :data:`TRAFFIC_DEFAULTS` for MixedTraffic)
    :return: the checkpoint path
    """
    ds = dataset if isinstance(dataset, OfflineDataset) else load_dataset(dataset)
    settings = env_settings(ds)
    kwargs = {**(TRAFFIC_DEFAULTS if settings["env_id"] == "MixedTraffic-v0" else {}), **(algo_kwargs or {})}
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
    entropy_threshold: float | None = None,
    seed: int = 0,
    progress_bar: bool = False,
    callback: Any = None,
    algo_overrides: dict[str, Any] | None = None,
    monitor_file: str | os.PathLike | None = None,
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
    :param entropy_threshold: override δ (``inf`` = fixed chunk execution)
    :param seed: seed of the online phase
    :param callback: SB3 callback(s) passed to ``learn``
    :param algo_overrides: further attributes to override on load (e.g. ``{"gradient_steps": 1}``);
        ``n_elite`` sets the policy's elite mean (``UA2C.load``: rollouts and the saved checkpoint act
        by it); shape-changing arguments (``chunk_size``, ``history_len``,
        ``policy_kwargs``) are refused
    :param monitor_file: write SB3's ``Monitor`` log of the online episodes (return, length, wall
        time and ``collision``) to this CSV file (``.monitor.csv`` is appended unless present); read
        it back with :func:`read_monitor`
    :return: the fine-tuned checkpoint path
    """
    ds = None
    if dataset is not None:
        ds = dataset if isinstance(dataset, OfflineDataset) else load_dataset(dataset)
    settings = env_settings(ds) if ds is not None else dict(env_settings_ or {"env_id": "MixedTraffic-v0"})
    shape_args = {"chunk_size", "history_len", "policy_kwargs"} & set(algo_overrides or {})
    if shape_args:
        raise ValueError(f"algo_overrides cannot change the network shapes of a checkpoint: {sorted(shape_args)}")
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


@dataclass(frozen=True)
class EpisodeMetrics:
    """What :func:`evaluate` measures per episode (``MixedTraffic-v0`` info keys)."""

    seed: int
    reward: float
    length: int
    cumulative_jerk: float  # Σ_t |jerk_t| [m/s³], the smoothness cost of Fig. 2(b)
    collision: bool
    merge_success: bool
    mean_speed: float  # [m/s]
    mean_executed_length: float  # mean L_t of the plans made in the episode (Eq. 7)

    @property
    def jerk_per_step(self) -> float:
        """``cumulative_jerk / length`` [m/s³]: smoothness that does not reward ending an episode early."""
        return self.cumulative_jerk / self.length if self.length else math.nan


def evaluate(
    checkpoint: str | os.PathLike | UA2C | Any,
    n_episodes: int = 5,
    seeds: tuple[int, ...] = (0,),
    env_settings_: dict[str, Any] | None = None,
    entropy_threshold: float | None = None,
    deterministic: bool = True,
    n_elite: int | None = None,
    flow_steps: int | None = None,
) -> list[EpisodeMetrics]:
    """Run a checkpoint for ``n_episodes`` episodes per seed with the stateful ``predict``.

    Episode ``i`` of seed ``s`` is reset with seed ``1000 * s + i`` (the same scenarios for every
    checkpoint evaluated with the same seeds). With ``deterministic=False`` every replanning draws
    fresh candidate noise, as the rollouts of Phase 2 do; the noise of an episode comes from torch's
    generator seeded with the episode's seed (the global generator is restored afterwards), so
    sampled evaluations are reproducible too.

    :param checkpoint: a UA2C ``.zip`` path, a UA2C model, or any policy with SB3's
        ``predict(obs, state=None, episode_start=None, deterministic=True)`` and
        ``observation_space``/``action_space`` (e.g. SB3's SAC, or :mod:`sb3_ua2c.peers`' adapter of a
        d3rlpy policy): such a policy acts one action per decision (``mean_executed_length`` 1) and
        takes none of the UA2C overrides below
    :param n_episodes: episodes per seed
    :param seeds: evaluation seeds
    :param env_settings_: ``make_env`` arguments (default ``MixedTraffic-v0``)
    :param entropy_threshold: override δ for execution
    :param deterministic: fixed candidate noise (see ``UA2CPolicy.predict``); ``False``: fresh,
        seeded noise per replanning
    :param n_elite: override how many best candidates a replanning averages (``UA2C.set_n_elite``)
    :param flow_steps: override the Euler steps of the sampler when acting (``UA2C.set_flow_steps``)
    """
    check_int("n_episodes", n_episodes)
    settings = dict(env_settings_ or {"env_id": "MixedTraffic-v0"})
    env = make_env(**settings)
    try:
        if isinstance(checkpoint, str | os.PathLike):
            model = load_checkpoint(checkpoint, env)
        elif isinstance(checkpoint, UA2C) or callable(getattr(checkpoint, "predict", None)):
            model = checkpoint
            check_spaces_match(model.observation_space, model.action_space, env, what="the model")
        else:
            raise TypeError(f"checkpoint must be a path or a policy with predict(), got {type(checkpoint).__name__}")
        overrides = {"entropy_threshold": entropy_threshold, "n_elite": n_elite, "flow_steps": flow_steps}
        given = sorted(name for name, value in overrides.items() if value is not None)
        if given and not isinstance(model, UA2C):
            raise ValueError(f"{given} apply to UA2C only, not to a {type(model).__name__}")
        if entropy_threshold is not None:
            model.set_entropy_threshold(entropy_threshold)
        if n_elite is not None:
            model.set_n_elite(n_elite)
        if flow_steps is not None:
            model.set_flow_steps(flow_steps)
        results = []
        for s in seeds:
            for i in range(n_episodes):
                results.append(_run_episode(model, env, 1000 * int(s) + i, deterministic))
        return results
    finally:
        env.close()


def _run_episode(model: Any, env: Any, seed: int, deterministic: bool) -> EpisodeMetrics:
    if deterministic:
        return _drive_episode(model, env, seed, deterministic)
    with th.random.fork_rng(devices=[]):  # seeded candidate noise, the caller's generator untouched
        th.manual_seed(seed)
        return _drive_episode(model, env, seed, deterministic)


def _drive_episode(model: Any, env: Any, seed: int, deterministic: bool) -> EpisodeMetrics:
    obs, info = env.reset(seed=seed)
    state, start = None, np.ones(1, dtype=bool)
    total, jerk, speeds, lengths = 0.0, 0.0, [], []
    collision = merged = False
    steps = 0
    done = False
    while not done:
        action, state = model.predict(obs, state=state, episode_start=start, deterministic=deterministic)
        if not hasattr(state, "plan_position"):  # a one-action-per-decision policy
            lengths.append(1)
        elif int(state.plan_position[0]) == 1:  # a plan was made at this step
            lengths.append(int(state.plan_length[0]))
        start = np.zeros(1, dtype=bool)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        jerk += abs(float(info.get("jerk", 0.0)))
        speeds.append(float(info.get("av_speed", math.nan)))
        collision |= bool(info.get("collision", False))
        merged |= bool(info.get("merge_done", False))
        steps += 1
        done = terminated or truncated
    return EpisodeMetrics(
        seed=seed, reward=total, length=steps, cumulative_jerk=jerk, collision=collision,
        merge_success=merged, mean_speed=float(np.nanmean(speeds)), mean_executed_length=float(np.mean(lengths)),
    )


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


SUMMARY_KEYS = (
    "reward", "cumulative_jerk", "jerk_per_step", "collision", "merge_success", "mean_speed", "mean_executed_length",
)


def summarize(results: list[EpisodeMetrics]) -> dict[str, float]:
    """Means over episodes (collision and merge as rates) plus the episode count."""
    if not results:
        raise ValueError("no episodes to summarize")
    out = {key: float(np.mean([float(getattr(r, key)) for r in results])) for key in SUMMARY_KEYS}
    out["episodes"] = len(results)
    return out


def format_table(rows: dict[str, dict[str, float]]) -> str:
    """A plain-text table, one row per method."""
    headers = ("method", "reward", "cum. jerk", "collision", "merge", "speed", "mean L_t")
    lines = [" | ".join(f"{h:>12}" for h in headers)]
    lines.append("-|-".join("-" * 12 for _ in headers))
    for name, s in rows.items():
        values = (s["reward"], s["cumulative_jerk"], s["collision"], s["merge_success"], s["mean_speed"], s["mean_executed_length"])
        lines.append(" | ".join([f"{name:>12}"] + [f"{v:12.3f}" for v in values]))
    return "\n".join(lines)


def write_json(path: str | os.PathLike, payload: Any) -> Path:
    """Write JSON atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True, default=_json_default))
    os.replace(tmp, path)
    return path


def _json_default(obj: Any) -> Any:
    if isinstance(obj, EpisodeMetrics):
        return asdict(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


__all__ = [
    "TRAFFIC_DEFAULTS", "EpisodeMetrics", "OfflineDatasetError", "evaluate", "finetune", "format_table",
    "load_checkpoint", "pretrain", "read_monitor", "save_atomic", "summarize", "write_json",
]
