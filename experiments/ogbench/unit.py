"""One unit of the OGBench benchmark, (arm, task, seed): UA2C pre-trained, evaluated, fine-tuned online and
evaluated again; the arms differ in their chunking only (:data:`ARMS`)."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from experiments.common.budget import Budget, Check, flag, integer, optional, reserved_keys
from experiments.common.records import recorded_path
from experiments.ogbench.data import TaskName, generate_play_dataset, load_singletask, to_episodes, val_path
from experiments.ogbench.env import ENV_ID, OGBenchSingleTask
from sb3_ua2c.execution import length_shares
from sb3_ua2c.offline import OfflineDataset
from sb3_ua2c.pipeline import finetune, load_checkpoint, pretrain, write_json

#: UA2C arguments of the arms (everything else is the budget's ``algo_kwargs``, the same for all):
#: ``adaptive`` is UA2C's default chunking (k and δ), ``fixed`` executes every chunk in full (δ = inf: how
#: Q-chunking acts), ``onestep`` replans every step (k = 1).
ARMS: dict[str, dict[str, Any]] = {"adaptive": {}, "fixed": {"entropy_threshold": math.inf},
                                   "onestep": {"chunk_size": 1}}

#: Evaluation episode ``i`` of seed ``s`` resets with seed ``EVAL_SEED_BASE + 1000 * s + i``: the scenarios of
#: the reported numbers (test). Choices (the execution-rule screen) use ``VALIDATION_SEED_BASE`` instead.
EVAL_SEED_BASE = 10_000_000
VALIDATION_SEED_BASE = 20_000_000


@dataclass(frozen=True)
class OGBenchBudget(Budget):
    """Budget of one unit; a bad value raises ``ValueError`` naming it."""

    dataset_episodes: int = 200  # of the generated dataset, one per domain (shared by arms and seeds)
    episode_steps: int = 1001  # per dataset episode, as OGBench's
    data_seed: int = 0
    pretrain_steps: int = 20_000  # Phase-1 gradient steps
    finetune_steps: int = 20_000  # Phase-2 env steps
    train_freq: int = 5  # Phase-2 env steps per gradient step, the same for every arm
    eval_episodes: int = 50  # after each phase
    curve_points: int = 4  # evaluations during Phase 2, of curve_episodes each
    curve_episodes: int = 10
    sparse: bool = False  # Q-chunking's sparse reward
    max_episode_steps: int | None = None  # None: OGBench's time limit (shorter for quick checks only)
    algo_kwargs: Mapping[str, Any] = field(default_factory=dict)  # UA2C's arguments for every arm

    CHECKS: ClassVar[Mapping[str, Check]] = {
        **{name: integer() for name in ("dataset_episodes", "pretrain_steps", "finetune_steps", "train_freq",
                                        "eval_episodes", "curve_episodes")},
        "episode_steps": integer(low=2), "data_seed": integer(low=0), "curve_points": integer(low=0),
        "max_episode_steps": optional(integer()), "sparse": flag,
        "algo_kwargs": reserved_keys("chunk_size", "entropy_threshold", why="the arm sets them"),
    }

    @property
    def env_kwargs(self) -> dict[str, Any]:
        """The :class:`OGBenchSingleTask` arguments of the online and evaluation episodes."""
        return {"sparse": self.sparse, "max_episode_steps": self.max_episode_steps}

    def arm_kwargs(self, arm: Mapping[str, Any]) -> dict[str, Any]:
        """UA2C's arguments of an arm: ``algo_kwargs``, the arm's, and a buffer that holds Phase 2."""
        return {"buffer_size": max(self.finetune_steps, 1), **self.algo_kwargs, **arm}

    @property
    def cadence(self) -> dict[str, int]:
        """Phase 2's updates, the same for every arm (the adaptive arm would otherwise update once per plan)."""
        return {"train_freq": self.train_freq, "gradient_steps": 1}  # same as default: the cadence


def dataset_file(task: str, budget: OGBenchBudget, data_dir: str | os.PathLike) -> Path:
    """Where the unit's dataset lives: ``<data_dir>/<n>ep-<steps>-s<seed>/<domain>-play-v0.npz``."""
    name = TaskName.parse(task)
    return Path(data_dir) / f"{budget.dataset_episodes}ep-{budget.episode_steps}-s{budget.data_seed}" / name.dataset_file


def ensure_dataset(task: str, budget: OGBenchBudget, data_dir: str | os.PathLike) -> tuple[Path, dict[str, Any] | None]:
    """The dataset of ``task`` at ``budget``, generated if missing: its path and the generation's measurements."""
    path = dataset_file(task, budget, data_dir)
    if path.is_file() and val_path(path).is_file():
        return path, None
    return path, generate_play_dataset(task, path, budget.dataset_episodes, budget.episode_steps, budget.data_seed)


def offline_dataset(task: str, path: Path, env_kwargs: Mapping[str, Any]) -> OfflineDataset:
    """The generated data as an :class:`~sb3_ua2c.offline.OfflineDataset` of :class:`OGBenchSingleTask`."""
    env, train, _ = load_singletask(task, path, sparse=bool(env_kwargs.get("sparse", False)))
    env.close()
    probe = OGBenchSingleTask(task, **env_kwargs)
    spaces = probe.observation_space, probe.action_space
    probe.close()
    metadata = {"env_id": f"experiments.ogbench:{ENV_ID}", "env_kwargs": {"task": task, **env_kwargs},
                "style_classifier": None, "behaviour": "ogbench-play-oracle"}
    return OfflineDataset(path, to_episodes(train), *spaces, metadata)


def run_episodes(model: Any, env: OGBenchSingleTask, n_episodes: int, seed: int, deterministic: bool = True,
                 seed_base: int = EVAL_SEED_BASE) -> tuple[list[dict[str, float]], list[int]]:
    """``n_episodes`` of ``model``, episode ``i`` reset with ``seed_base + 1000 * seed + i``: one row per episode and
    the executed length ``L_t`` of every plan."""
    rows, plans = [], []
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed_base + 1000 * seed + i)
        state, start = None, np.ones(1, dtype=bool)
        done, success, total, steps = False, False, 0.0, 0
        while not done:
            action, state = model.predict(obs, state=state, episode_start=start, deterministic=deterministic)
            if int(state.plan_position[0]) == 1:  # a plan was made at this step
                plans.append(int(state.plan_length[0]))
            start = np.zeros(1, dtype=bool)
            obs, reward, terminated, truncated, info = env.step(action)
            success |= info["success"]
            total += reward
            steps += 1
            done = terminated or truncated
        rows.append({"success": float(success), "return": float(total), "length": steps})
    return rows, plans


def evaluate_success(model: Any, env: OGBenchSingleTask, n_episodes: int, seed: int) -> dict[str, Any]:
    """Success rate of ``model`` over ``n_episodes`` (:func:`run_episodes`) and the shares of its ``L_t``."""
    rows, plans = run_episodes(model, env, n_episodes, seed)
    return {"success": float(np.mean([r["success"] for r in rows])), "successes": [r["success"] for r in rows],
            "lengths": [r["length"] for r in rows], "returns": [r["return"] for r in rows],
            "length_shares": length_shares(plans, model.chunk_size)}


class _OnlineCurve(BaseCallback):
    """Records Phase-2 training episodes and evaluates at ``eval_at`` environment steps."""

    def __init__(self, env: OGBenchSingleTask, eval_at: list[int], episodes: int, seed: int) -> None:
        super().__init__()
        self.env, self.eval_at, self.episodes, self.seed = env, list(eval_at), episodes, seed
        self.training: list[dict[str, float]] = []
        self.evaluations: list[dict[str, Any]] = []
        self._return = 0.0

    def _on_step(self) -> bool:
        info, reward, done = self.locals["infos"][0], float(self.locals["rewards"][0]), bool(self.locals["dones"][0])
        self._return += reward
        if done:
            self.training.append({"step": self.num_timesteps, "success": float(info["success"]), "return": self._return})
            self._return = 0.0
        while self.eval_at and self.num_timesteps >= self.eval_at[0]:
            result = evaluate_success(self.model, self.env, self.episodes, self.seed)
            self.evaluations.append({"step": self.eval_at.pop(0), "success": result["success"]})
        return True


def run_ogbench_unit(arm: str, task: str, seed: int, budget: OGBenchBudget, out_dir: str | os.PathLike,
                     data_dir: str | os.PathLike | None = None) -> dict[str, Any]:
    """Run one unit into ``out_dir`` (the dataset in ``data_dir``, default ``<out_dir>/data``); return its record."""
    if arm not in ARMS:
        raise ValueError(f"arm must be one of {sorted(ARMS)}, got {arm!r}")
    TaskName.parse(task)
    integer(low=0)("seed", seed)
    if not isinstance(budget, OGBenchBudget):
        raise TypeError(f"budget must be an OGBenchBudget, got {type(budget).__name__}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    th.set_num_threads(1)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    path, generation = ensure_dataset(task, budget, data_dir if data_dir is not None else out / "data")
    ds = offline_dataset(task, path, budget.env_kwargs)
    times: dict[str, float] = {"data_wall": time.perf_counter() - wall0, "data_cpu": time.process_time() - cpu0}
    kwargs = budget.arm_kwargs(ARMS[arm])

    def phase(name: str, fn: Any) -> Any:
        wall, cpu = time.perf_counter(), time.process_time()
        result = fn()
        times[f"{name}_wall"], times[f"{name}_cpu"] = time.perf_counter() - wall, time.process_time() - cpu
        return result

    env = OGBenchSingleTask(task, **budget.env_kwargs)
    try:
        ckpt = phase("pretrain", lambda: pretrain(ds, out / "pretrained.zip", budget.pretrain_steps, seed=seed,
                                                  algo_kwargs=kwargs))
        offline_eval = phase("eval_offline", lambda: evaluate_success(load_checkpoint(ckpt, env), env,
                                                                       budget.eval_episodes, seed))
        every = budget.finetune_steps / (budget.curve_points + 1)
        curve = _OnlineCurve(env, [round(every * (i + 1)) for i in range(budget.curve_points)],
                             budget.curve_episodes, seed)
        tuned = phase("finetune", lambda: finetune(ckpt, out / "finetuned.zip", budget.finetune_steps, dataset=ds,
                                                   seed=seed, callback=curve, algo_overrides=budget.cadence))
        online_eval = phase("eval_online", lambda: evaluate_success(load_checkpoint(tuned, env), env,
                                                                     budget.eval_episodes, seed))
    finally:
        env.close()
    times["total_wall"], times["total_cpu"] = time.perf_counter() - wall0, time.process_time() - cpu0
    record = {
        "arm": arm, "task": task, "seed": seed, "budget": budget.to_dict(),
        "algo_kwargs": {k: str(v) if isinstance(v, float) and math.isinf(v) else v for k, v in kwargs.items()},
        "dataset": {"path": recorded_path(path), "transitions": ds.total_steps, "segments": len(ds), "generation": generation},
        "success_offline": offline_eval["success"], "success_online": online_eval["success"],
        "eval_offline": offline_eval, "eval_online": online_eval,
        "curve": [{"step": 0, "success": offline_eval["success"]}, *curve.evaluations,
                  {"step": budget.finetune_steps, "success": online_eval["success"]}],
        "training_episodes": curve.training, "seconds": times,
    }
    write_json(out / "record.json", record)
    return record
