"""One run (seed) of the execution-rule study: data, Phase 1, one Phase-2 checkpoint per online rule, and every
checkpoint evaluated under the screened rules and their controls (:func:`evaluate_rules`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from envs.collection import TRAFFIC_DEFAULTS, collect_dataset, make_traffic_env
from envs.evaluation import evaluate
from experiments.common.names import DATASET_SEED_BASE
from experiments.common.records import episode_rows
from experiments.execution.controls import RULES, FixedCut, RandomCut, apply_control, apply_rule
from experiments.ogbench.env import OGBenchSingleTask
from experiments.ogbench.runner import default_budget
from experiments.ogbench.unit import OGBenchBudget, ensure_dataset, offline_dataset, run_episodes
from sb3_ua2c.execution import length_shares
from sb3_ua2c.pipeline import env_settings, finetune, load_checkpoint, pretrain

#: ``make main``'s budget (``MAIN_BUDGET["full"]`` of ``envs/cli.py``) and a smoke-test one
BUDGETS = {
    "full": {"episodes": 200, "pretrain_steps": 3000, "finetune_steps": 6000, "eval_episodes": 20},
    "quick": {"episodes": 3, "pretrain_steps": 8, "finetune_steps": 30, "eval_episodes": 1, "time_limit": 4.0},
}


#: ``run_episodes(model, deterministic) -> (episode rows, executed lengths L_t of every plan)``: one evaluation on
#: the run's scenarios (each study's ``episodes``)
EpisodeRunner = Callable[[Any, bool], tuple[list[dict[str, Any]], list[int]]]


def evaluate_rules(model: Any, rules: Sequence[str], calibration: Sequence[Any], run_episodes: EpisodeRunner,
                   control_seed: int) -> dict[str, Any]:
    """Each rule in both modes, then its controls (a random cut from its ``L_t`` shares, fixed ``k'``)."""
    out: dict[str, Any] = {}
    for name in rules:
        for mode, deterministic in (("deterministic", True), ("sampled", False)):
            apply_rule(model, RULES[name], calibration)
            thresholds = model.policy.calibrated_thresholds
            rows, lengths = run_episodes(model, deterministic)
            shares = length_shares(lengths, model.chunk_size)
            out.setdefault(name, {})[mode] = {"episodes": rows, "length_shares": shares,
                                              "thresholds": None if thresholds is None else thresholds.tolist()}
            if name == "fixed":
                continue
            k_prime = int(np.clip(round(float(np.mean(lengths))), 1, model.chunk_size))
            for control, rule in ((f"{name}:random", RandomCut(shares, control_seed)),
                                  (f"{name}:fixed_k", FixedCut(k_prime, model.chunk_size))):
                apply_control(model, rule)
                rows, control_lengths = run_episodes(model, deterministic)
                out.setdefault(control, {})[mode] = {"episodes": rows, "k": k_prime,
                                                     "length_shares": length_shares(control_lengths, model.chunk_size)}
            apply_rule(model, RULES["fixed"])
    return out


def checkpoint_rules(name: str, screened_rules: Sequence[str], own_rule_only: bool) -> list[str]:
    """Every screened rule, or with ``own_rule_only`` for a fine-tuned checkpoint fixed chunks and its own rule."""
    if own_rule_only and name != "offline":
        return list(dict.fromkeys(["fixed", name.removeprefix("online_")]))
    return list(screened_rules)


def run_traffic_study(seed: int, work: str, budget: Mapping[str, int], online_rules: Sequence[str],
                      screened_rules: Sequence[str], scenario_base: int, own_rule_only: bool = False) -> dict[str, Any]:
    """One run on ``MixedTraffic-v0`` with ``make main``'s pipeline and budget (see the module docstring)."""
    th.set_num_threads(1)
    root = Path(work) / f"seed{seed}"
    env_kwargs = {"time_limit": budget["time_limit"]} if "time_limit" in budget else None
    ds = collect_dataset(root / "dataset", budget["episodes"], seed=DATASET_SEED_BASE + 10_000 * seed,
                         env_kwargs=env_kwargs, style_classifier="default", overwrite=True)
    pre = pretrain(ds, root / "pretrained.zip", budget["pretrain_steps"], seed=seed, algo_kwargs=TRAFFIC_DEFAULTS,
                   make_env=make_traffic_env)
    settings = env_settings(ds)
    checkpoints = {"offline": pre}
    for rule in online_rules:
        checkpoints[f"online_{rule}"] = finetune(pre, root / f"online_{rule}.zip", budget["finetune_steps"], dataset=ds,
                                                 seed=seed, algo_overrides=dict(RULES[rule]), make_env=make_traffic_env)

    def episodes(model: Any, deterministic: bool) -> tuple[list[dict[str, Any]], list[int]]:  # :func:`evaluate`
        results = evaluate(model, n_episodes=budget["eval_episodes"], seeds=(scenario_base + seed,),
                           env_settings_=dict(settings), deterministic=deterministic)
        return episode_rows(results), [n for e in results for n in e.plan_lengths]

    return {"seed": seed, "budget": dict(budget), "scenario_seed": scenario_base + seed,
            "dataset_mean_return": ds.metadata["mean_return"],
            "checkpoints": evaluate_checkpoints(checkpoints, make_traffic_env(**settings), episodes, ds.episodes,
                                                screened_rules, own_rule_only, seed)}


def evaluate_checkpoints(checkpoints: Mapping[str, Any], env: Any, run_episodes: EpisodeRunner,
                         calibration: Sequence[Any], screened_rules: Sequence[str], own_rule_only: bool,
                         seed: int) -> dict[str, Any]:
    """:func:`evaluate_rules` of every checkpoint loaded on ``env`` (closed afterwards) under its rules."""
    try:
        return {name: evaluate_rules(load_checkpoint(path, env), checkpoint_rules(name, screened_rules, own_rule_only),
                                     calibration, run_episodes, control_seed=seed) for name, path in checkpoints.items()}
    finally:
        env.close()


# ------------------------------------------------------------------------------------ OGBench
# The second task next to MixedTraffic-v0: the OGBench harness's data, Phase 1 of the chunk policy at its
# budget, one Phase-2 checkpoint per online rule, and every checkpoint evaluated under the screened rules and
# their controls, deterministic and with fresh noise. The score is the success rate; the scenarios are reset
# seeds ``scenario_base + 1000 * seed + i`` (``VALIDATION_SEED_BASE`` of :mod:`experiments.ogbench.unit` for
# the screen, ``EVAL_SEED_BASE`` to confirm).

#: Evaluation episodes per checkpoint, arm and mode of the OGBench study (the OGBench report: 50)
OGBENCH_EVAL_EPISODES = 20


def study_budget(task: str, quick: bool = False) -> Any:
    """The OGBench harness's budget of ``task``, with :data:`OGBENCH_EVAL_EPISODES` evaluation episodes unless ``quick``."""
    budget = default_budget(task, quick)
    return budget if quick else dataclasses.replace(budget, eval_episodes=OGBENCH_EVAL_EPISODES)


def run_ogbench_study(seed: int, work: str, budget: Mapping[str, Any], task: str, online_rules: Sequence[str],
                      screened_rules: Sequence[str], scenario_base: int, own_rule_only: bool = False) -> dict[str, Any]:
    """One run on an OGBench ``task`` (``budget``: an :class:`OGBenchBudget` as a dict)."""
    th.set_num_threads(1)
    b = OGBenchBudget.from_dict(budget)
    root = Path(work) / f"seed{seed}"
    path, _ = ensure_dataset(task, b, Path(work) / "data")  # one dataset per domain, shared by the seeds
    ds = offline_dataset(task, path, b.env_kwargs)
    kwargs = b.arm_kwargs({})  # UA2C's default k, as the OGBench harness's adaptive and fixed arms
    checkpoints = {"offline": pretrain(ds, root / "pretrained.zip", b.pretrain_steps, seed=seed, algo_kwargs=kwargs)}
    for rule in online_rules:  # the same cadence for every rule
        checkpoints[f"online_{rule}"] = finetune(checkpoints["offline"], root / f"online_{rule}.zip", b.finetune_steps,
                                                 dataset=ds, seed=seed, algo_overrides={**RULES[rule], **b.cadence})
    env = OGBenchSingleTask(task, **b.env_kwargs)

    def episodes(model: Any, deterministic: bool) -> tuple[list[dict[str, Any]], list[int]]:  # the task's reset seeds
        return run_episodes(model, env, b.eval_episodes, seed, deterministic=deterministic, seed_base=scenario_base)

    return {"seed": seed, "task": task, "budget": b.to_dict(), "scenario_seed": scenario_base + 1000 * seed,
            "checkpoints": evaluate_checkpoints(checkpoints, env, episodes, ds.episodes, screened_rules, own_rule_only,
                                                seed)}
