"""One run of the execution-rule study on an OGBench task (:func:`run_ogbench_study`), the second task next to
``MixedTraffic-v0``: the OGBench harness's data, Phase 1 of the chunk policy (k = 5) at its budget, one Phase-2
checkpoint per online rule, and every checkpoint evaluated under the screened rules and their controls
(:func:`~experiments.execution.unit.evaluate_rules`), deterministic and with fresh noise. The score is the
success rate; the scenarios are reset seeds ``scenario_base + 1000 * seed + i``
(:data:`~experiments.ogbench.unit.VALIDATION_SEED_BASE` for the screen, ``EVAL_SEED_BASE`` to confirm)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch as th

from experiments.execution.controls import RULES
from experiments.execution.unit import EpisodeRunner, checkpoint_rules, evaluate_rules
from experiments.ogbench.env import OGBenchSingleTask
from experiments.ogbench.runner import default_budget
from experiments.ogbench.unit import OGBenchBudget, ensure_dataset, offline_dataset, run_episodes
from sb3_ua2c.pipeline import finetune, load_checkpoint, pretrain

#: The chunk length of the study's policy (the OGBench harness's adaptive and fixed arms)
CHUNK_SIZE = 5
#: Evaluation episodes per checkpoint, arm and mode (the OGBench report: 50)
EVAL_EPISODES = 20


def study_budget(task: str, quick: bool = False) -> OGBenchBudget:
    """The OGBench harness's budget of ``task`` (:func:`~experiments.ogbench.runner.default_budget`; a bad task
    raises ``ValueError`` naming ``--task``), with :data:`EVAL_EPISODES` evaluation episodes unless ``quick``."""
    budget = default_budget(task, quick)
    return budget if quick else dataclasses.replace(budget, eval_episodes=EVAL_EPISODES)


def ogbench_episodes(env: OGBenchSingleTask, n_episodes: int, seed: int, scenario_base: int) -> EpisodeRunner:
    """The task's evaluation on the run's reset seeds, as the study's :data:`EpisodeRunner`."""

    def run(model: Any, deterministic: bool) -> tuple[list[dict[str, Any]], list[int]]:
        return run_episodes(model, env, n_episodes, seed, deterministic=deterministic, seed_base=scenario_base)

    return run


def run_ogbench_study(seed: int, work: str, budget: Mapping[str, Any], task: str, online_rules: Sequence[str],
             screened_rules: Sequence[str], scenario_base: int, own_rule_only: bool = False) -> dict[str, Any]:
    """One run (see the module docstring); the arguments are those of
    :func:`experiments.execution.unit.run_traffic_study`, with ``budget`` an :class:`OGBenchBudget` as a dict and the
    OGBench ``task``."""
    th.set_num_threads(1)
    b = OGBenchBudget.from_dict(budget)
    root = Path(work) / f"seed{seed}"
    path, _ = ensure_dataset(task, b, Path(work) / "data")  # one dataset per domain, shared by the seeds
    env_kwargs = {"sparse": b.sparse, "max_episode_steps": b.max_episode_steps}
    ds = offline_dataset(task, path, env_kwargs)
    kwargs = {**b.algo_kwargs, "chunk_size": CHUNK_SIZE}
    kwargs.setdefault("buffer_size", max(b.finetune_steps, 1))
    checkpoints = {"offline": pretrain(ds, root / "pretrained.zip", b.pretrain_steps, seed=seed, algo_kwargs=kwargs)}
    for rule in online_rules:  # the same cadence for every rule: one update per train_freq env steps
        overrides = {**RULES[rule], "train_freq": b.train_freq, "gradient_steps": 1}
        checkpoints[f"online_{rule}"] = finetune(checkpoints["offline"], root / f"online_{rule}.zip", b.finetune_steps,
                                                 dataset=ds, seed=seed, algo_overrides=overrides)
    record: dict[str, Any] = {"seed": seed, "task": task, "budget": b.to_dict(),
                              "scenario_seed": scenario_base + 1000 * seed, "checkpoints": {}}
    env = OGBenchSingleTask(task, **env_kwargs)
    try:
        runner = ogbench_episodes(env, b.eval_episodes, seed, scenario_base)
        for name, ckpt in checkpoints.items():
            rules = checkpoint_rules(name, screened_rules, own_rule_only)
            record["checkpoints"][name] = evaluate_rules(load_checkpoint(ckpt, env), rules, ds.episodes, runner,
                                                         control_seed=seed)
    finally:
        env.close()
    return record
