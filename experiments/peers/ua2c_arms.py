"""The UA2C side of the head-to-head: Figure 2's per-seed dataset and checkpoints, and one unit per UA2C arm."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import CheckpointCallback

from envs.collection import TRAFFIC_DEFAULTS, collect_dataset, make_traffic_env
from experiments.common.records import recorded_path
from experiments.fig2.units import complete_dataset
from experiments.peers import common
from experiments.peers.budget import describe_ua2c_arm
from sb3_ua2c.pipeline import env_settings, finetune, pretrain


def build_dataset(path: str | os.PathLike, n_episodes: int, seed: int, env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage 1 of a seed: its offline dataset at ``path``, collected unless a complete one is there."""
    path = Path(path)
    ds = complete_dataset(path, n_episodes) or collect_dataset(path, n_episodes, env_kwargs=dict(env_kwargs), seed=seed,
                                                               overwrite=True)
    return {"path": recorded_path(path), "episodes": len(ds), "transitions": ds.total_steps, "seed": seed}


def build_checkpoint(dataset: str | os.PathLike, out: str | os.PathLike, pretrain_steps: int, seed: int,
                     algo_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage 2 of a seed: pre-train UA2C offline on the seed's dataset into ``out`` (Figure 2's Phase 1)."""
    th.set_num_threads(1)
    clock = common.PhaseClock()
    with clock.phase("offline"):
        path = pretrain(dataset, out, pretrain_steps, seed=seed, algo_kwargs={**TRAFFIC_DEFAULTS, **algo_kwargs},
                        make_env=make_traffic_env)
    return {"checkpoint": str(path), "pretrain_steps": pretrain_steps, "seed": seed,
            "algo_kwargs": dict(algo_kwargs), **clock.as_dict()}


def run_ua2c_arm(inputs: common.ArmInputs, arm: str, checkpoint: str | os.PathLike, delta: float | None,
                 finetune_overrides: Mapping[str, Any], pretrain_record: Mapping[str, Any],
                 snapshot_every: int = 0) -> dict[str, Any]:
    """One unit: a UA2C arm from the seed's ``checkpoint``, acting with ``delta``, evaluated, fine-tuned online and
    evaluated again. ``snapshot_every > 0`` also saves the model every that many online steps, as
    ``snapshots/model_<steps>_steps.zip`` of the arm's directory (SB3's ``CheckpointCallback``: the frozen checkpoints
    that ``python -m experiments acting`` evaluates)."""
    th.set_num_threads(1)
    ds = inputs.load_dataset()
    settings = env_settings(ds)
    out = Path(inputs.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clock = common.PhaseClock()
    snapshots = CheckpointCallback(snapshot_every, str(out / "snapshots"), "model") if snapshot_every > 0 else None
    with clock.phase("evaluate_offline"):
        offline_evaluation = common.evaluation_record(checkpoint, settings, inputs, entropy_threshold=delta)
    with clock.phase("online"):
        tuned = finetune(checkpoint, out / "model.zip", inputs.online_steps, dataset=ds, entropy_threshold=delta,
                         seed=inputs.seed, algo_overrides=dict(finetune_overrides), monitor_file=out / "online",
                         make_env=make_traffic_env, callback=snapshots)
    with clock.phase("evaluate"):
        evaluation = common.evaluation_record(tuned, settings, inputs, entropy_threshold=delta)
    # the shared offline phase, counted in every arm that starts from it
    clock.wall["offline"] = float(pretrain_record["wall_seconds"]["offline"])
    clock.cpu["offline"] = float(pretrain_record["cpu_seconds"]["offline"])
    hyper = {"algo": "ua2c", "delta": "inf" if delta == float("inf") else delta,
             "algo_kwargs": dict(pretrain_record["algo_kwargs"]), "finetune_overrides": dict(finetune_overrides)}
    return common.unit_record(arm, inputs, ds, inputs.online_steps, hyper, evaluation,
                              common.learning_curve(out / "online"), clock,
                              offline_steps=int(pretrain_record["pretrain_steps"]),
                              offline_evaluation=offline_evaluation, notes=describe_ua2c_arm(arm))
