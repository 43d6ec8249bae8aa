"""The UA2C side of the head-to-head: the per-seed shared stages (dataset, offline checkpoints) and
one unit per UA2C arm, each returning the same record as the peer units
(:func:`~experiments.peers.common.unit_record`).

The stages are Figure 2's (:mod:`experiments.fig2.units`): the seed's dataset is collected with
the same seed and behaviour policy, the checkpoints pre-trained with the same arguments and seed.
``ua2c``, ``ua2c_paper`` and Figure 2's arms at the defaults (``ua2c_fixed``, ``ua2c_onestep``) keep
their configuration's own update schedule; ``ua2c_adaptive`` runs with Figure 2's cadence (one
gradient step per ``chunk_size`` env steps, :func:`~experiments.fig2.units.finetune_overrides`)
(:data:`~experiments.peers.budget.UA2C_ARMS`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

from envs.collection import TRAFFIC_DEFAULTS, make_traffic_env
from experiments.peers.budget import describe_ua2c_arm
from experiments.peers.common import (
    ArmInputs,
    EvalProtocol,
    PhaseClock,
    learning_curve,
    read_dataset,
    recorded_path,
    unit_record,
)


def build_dataset(path: str | os.PathLike, n_episodes: int, seed: int, env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage 1 of a seed: collect its offline dataset at ``path`` (Figure 2's behaviour policy and
    seed), unless a complete one is there; return its description."""
    from envs.collection import collect_dataset
    from sb3_ua2c.offline import METADATA_FILE, OfflineDatasetError, load_dataset

    path = Path(path)
    ds = None
    if (path / METADATA_FILE).is_file():
        try:
            ds = load_dataset(path)
        except OfflineDatasetError:
            ds = None  # damaged: collect again
    if ds is None or len(ds) != n_episodes:
        ds = collect_dataset(path, n_episodes, env_kwargs=dict(env_kwargs), seed=seed, overwrite=True)
    return {"path": recorded_path(path), "episodes": len(ds), "transitions": ds.total_steps, "seed": seed}


def build_checkpoint(dataset: str | os.PathLike, out: str | os.PathLike, pretrain_steps: int, seed: int,
                     algo_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage 2 of a seed: pre-train UA2C offline on the seed's dataset into ``out`` (Figure 2's Phase 1)."""
    import torch as th

    from sb3_ua2c.pipeline import pretrain

    th.set_num_threads(1)
    clock = PhaseClock()
    with clock.phase("offline"):
        path = pretrain(dataset, out, pretrain_steps, seed=seed, algo_kwargs={**TRAFFIC_DEFAULTS, **algo_kwargs},
                        make_env=make_traffic_env)
    return {"checkpoint": str(path), "pretrain_steps": pretrain_steps, "seed": seed,
            "algo_kwargs": dict(algo_kwargs), **clock.as_dict()}


def ua2c_evaluation_record(checkpoint: str | os.PathLike, settings: Mapping[str, Any], protocol: EvalProtocol,
                           delta: float | None) -> dict[str, Any]:
    """A UA2C checkpoint acting with threshold ``delta`` on the protocol's scenarios (the record of
    :func:`~experiments.peers.common.evaluation_record`)."""
    from envs.evaluation import evaluate, summarize

    episodes = evaluate(checkpoint, n_episodes=protocol.episodes, seeds=protocol.seeds, env_settings_=dict(settings),
                        entropy_threshold=delta)
    rows = [{**asdict(e), "jerk_per_step": e.jerk_per_step} for e in episodes]
    return {"summary": summarize(episodes), "episodes": rows}


def run_ua2c_arm(inputs: ArmInputs, arm: str, checkpoint: str | os.PathLike, delta: float | None,
                 finetune_overrides: Mapping[str, Any], pretrain_record: Mapping[str, Any]) -> dict[str, Any]:
    """One unit: a UA2C arm from its pre-trained ``checkpoint`` (shared by the arms of the seed), evaluated
    offline with its own execution rule, fine-tuned online for ``online_steps`` env steps with the
    seed's offline data kept in its buffer, evaluated again.

    :param arm: the arm's name (``ua2c_adaptive``, ``ua2c_fixed``, ``ua2c_onestep``)
    :param delta: δ the arm acts and fine-tunes with (``inf``: fixed chunks; ``None``: the checkpoint's)
    :param finetune_overrides: Phase-2 attributes (:meth:`~experiments.peers.budget.PeersBudget.finetune_overrides`)
    :param pretrain_record: the record of :func:`build_checkpoint` (its time is counted in this arm's)
    :param inputs: the unit's directory, dataset, seed, online steps and evaluation scenarios
        (:class:`~experiments.peers.common.ArmInputs`)
    """
    import torch as th

    from sb3_ua2c.pipeline import env_settings, finetune

    th.set_num_threads(1)
    protocol, seed, online_steps = inputs.protocol, inputs.seed, inputs.online_steps
    ds = read_dataset(inputs.dataset)
    settings = env_settings(ds)
    out = Path(inputs.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clock = PhaseClock()
    with clock.phase("evaluate_offline"):
        offline_evaluation = ua2c_evaluation_record(checkpoint, settings, protocol, delta)
    with clock.phase("online"):
        tuned = finetune(checkpoint, out / "model.zip", online_steps, dataset=ds, entropy_threshold=delta, seed=seed,
                         algo_overrides=dict(finetune_overrides), monitor_file=out / "online", make_env=make_traffic_env)
    with clock.phase("evaluate"):
        evaluation = ua2c_evaluation_record(tuned, settings, protocol, delta)
    # the shared offline phase, counted in every arm that starts from it
    clock.wall["offline"] = float(pretrain_record["wall_seconds"]["offline"])
    clock.cpu["offline"] = float(pretrain_record["cpu_seconds"]["offline"])
    hyper = {"algo": "ua2c", "delta": "inf" if delta == float("inf") else delta,
             "algo_kwargs": dict(pretrain_record["algo_kwargs"]), "finetune_overrides": dict(finetune_overrides)}
    return unit_record(arm, seed, ds, protocol, online_steps, hyper, evaluation, learning_curve(out / "online"),
                       clock, offline_steps=int(pretrain_record["pretrain_steps"]),
                       offline_evaluation=offline_evaluation, notes=describe_ua2c_arm(arm))
