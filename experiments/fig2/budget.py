"""Configuration of a Figure-2 run: :class:`Fig2Budget`, its default and ``--quick`` budgets, and its directories."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from experiments.common import records
from experiments.common.budget import (
    Budget,
    Check,
    each,
    finite,
    flag,
    integer,
    library_default,
    mapping,
    reserved_keys,
)
from experiments.common.estimate import estimate, recorded, seconds_per_size
from experiments.common.names import MAIN_METHODS, SAMPLED_METHODS
from experiments.common.runner import list_schedule_seconds


def _deltas(label: str, values: Any) -> None:
    if any(math.isnan(float(d)) or float(d) == -math.inf for d in values):
        raise ValueError(f"{label} must hold numbers > -inf, got {values!r}")


@dataclass(frozen=True)
class Fig2Budget(Budget):
    """Budget and hyperparameters of one Figure-2 run, per seed (``docs/figure2.md``)."""

    dataset_episodes: int = 200  # offline episodes per seed (the behaviour policy of envs.collection)
    pretrain_steps: int = 6000  # Phase-1 gradient steps of every pre-trained arm
    finetune_steps: int = 10000  # Phase-2 env steps of every fine-tuned arm, one update per chunk_size steps
    eval_episodes: int = 20  # per method and seed, the same scenarios for every method
    chunk_size: int = 5  # same as default: the paper's Figure 2 runs k = 5
    entropy_threshold: float = 0.0  # same as default: the paper's adaptive arm runs δ = 0
    style_episodes: int = 400  # of the driving-style dataset per seed (>= 3: split by episode)
    style_max_epochs: int = 40  # of the style classifier (early stopping)
    delta_sweep: tuple[float, ...] = (-0.5, 0.0, 0.25, 0.5, 1.0, math.inf)  # δ the adaptive checkpoint acts with
    k_sweep: tuple[int, ...] = (1, 3, 5, 10)  # chunk lengths pre-trained for the k sweep
    style_ablation: bool = True  # the "adaptive + style context" arm
    elite_sweep: tuple[int, ...] = (4, 8, 16)  # n_elite the offline one-step and chunk checkpoints also act with
    flow_sweep: tuple[int, ...] = (2,)  # Euler steps N they also act with, with n_elite 1 and elite_sweep
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)  # MixedTraffic-v0's, for every unit
    algo_kwargs: Mapping[str, Any] = field(default_factory=dict)  # UA2C's, for every pre-trained arm
    onestep_kwargs: Mapping[str, Any] = field(default_factory=dict)  # over algo_kwargs for the one-step baseline
    finetune_kwargs: Mapping[str, Any] = field(default_factory=dict)  # UA2C attributes of Phase 2 only
    online_seed_offset: int = 0  # Phase 2 of seed s runs with s + MAX_SEED * offset
    online_replicates: int = 1  # online phases per seed from the same checkpoint, pooled into (c)
    sampled_eval: bool = True  # also evaluate SAMPLED_METHODS with fresh candidate noise

    CHECKS: ClassVar[Mapping[str, Check]] = {
        **{name: integer() for name in ("pretrain_steps", "finetune_steps", "chunk_size", "style_max_epochs",
                                        "online_replicates")},
        "dataset_episodes": integer(high=9_999), "style_episodes": integer(low=3, high=9_999),
        "eval_episodes": integer(high=1_000), "online_seed_offset": integer(low=0),
        "entropy_threshold": finite, "delta_sweep": _deltas, "k_sweep": each(integer()),
        "elite_sweep": each(integer()), "flow_sweep": each(integer()), "style_ablation": flag, "sampled_eval": flag,
        "env_kwargs": mapping, "finetune_kwargs": reserved_keys(
            "chunk_size", "entropy_threshold", "train_freq", "gradient_steps", why="the runner sets them"),
        **{name: reserved_keys("chunk_size", "entropy_threshold", why="they are Fig2Budget fields")
           for name in ("algo_kwargs", "onestep_kwargs")},
    }

    def validate(self) -> None:
        n_candidates = min(kwargs.get("n_candidates", library_default("n_candidates"))
                           for kwargs in (self.algo_kwargs, self.onestep_kwargs))
        if any(m > n_candidates for m in self.elite_sweep):
            raise ValueError(f"Fig2Budget.elite_sweep holds {max(self.elite_sweep)}, more than the {n_candidates} candidates")
        elites = {k: _policy_elite(self, k) for k in (1, self.chunk_size)}
        if elites[1] != elites[self.chunk_size]:  # (a) and (b) compare both arms acting by one rule
            raise ValueError(f"Fig2Budget.onestep_kwargs: the one-step baseline acts with n_elite={elites[1]} and "
                             f"the chunk policy with n_elite={elites[self.chunk_size]}; (a) and (b) need the same "
                             "acting rule")
        for name in ("k_sweep", "elite_sweep", "flow_sweep"):
            object.__setattr__(self, name, tuple(sorted({int(v) for v in getattr(self, name)})))
        object.__setattr__(self, "delta_sweep", tuple(sorted({float(d) for d in self.delta_sweep})))
        object.__setattr__(self, "entropy_threshold", float(self.entropy_threshold))

    @property
    def default_elite(self) -> int:
        """``n_elite`` the pre-trained arms act with (their ``policy_kwargs``, else UA2C's default; 1 = best-of-S)."""
        return _policy_elite(self, self.chunk_size)

    def acting_variants(self, default_elite: int | None = None) -> tuple[tuple[int | None, int], ...]:
        """``(flow_steps, n_elite)`` pairs of the acting sweep, but how (a) and (b) act."""
        m0 = self.default_elite if default_elite is None else default_elite
        elites = (m0, *sorted({1, *self.elite_sweep} - {m0}))
        pairs = [(n, m) for n in (None, *self.flow_sweep) for m in elites]
        return tuple(p for p in pairs if p != (None, m0))

    def arm_kwargs(self, k: int) -> dict[str, Any]:
        """UA2C constructor arguments of the pre-trained arm with chunk length ``k``."""
        extra = self.onestep_kwargs if k == 1 else {}
        return {**self.algo_kwargs, **extra, "chunk_size": k, "entropy_threshold": self.entropy_threshold}

    @property
    def pretrain_ks(self) -> tuple[int, ...]:
        """Chunk lengths pre-trained per seed: 1, ``chunk_size`` and the k sweep."""
        return tuple(sorted({1, self.chunk_size, *self.k_sweep}))


def _policy_elite(budget: Fig2Budget, k: int) -> int:
    """``policy_kwargs["n_elite"]`` of the arm with chunk length ``k`` (UA2C's default when unset)."""
    policy_kwargs = budget.arm_kwargs(k).get("policy_kwargs") or {}
    policy_kwargs = policy_kwargs if isinstance(policy_kwargs, Mapping) else {}
    return int(policy_kwargs.get("n_elite", library_default("policy_kwargs")["n_elite"]))


#: Default budget, about two hours for 5 seeds on 2 cores (its choices: ``docs/figure2.md``).
FULL_BUDGET = Fig2Budget(k_sweep=(1, 3, 5), onestep_kwargs={"policy_kwargs": {"net_arch": [128, 128]}},
                         online_replicates=2)


#: ``--quick``: 4-second episodes and a handful of updates, for smoke tests and CI.
QUICK_BUDGET = Fig2Budget(dataset_episodes=3, pretrain_steps=8, finetune_steps=30, eval_episodes=1, style_episodes=6,
                          style_max_epochs=2, delta_sweep=(0.0, math.inf), k_sweep=(1, 2, 3), elite_sweep=(2,),
                          flow_sweep=(2,), chunk_size=3, env_kwargs={"time_limit": 4.0},
                          algo_kwargs={"batch_size": 32}, online_replicates=2)


#: Budget fields that change what an existing unit holds; the sweeps may grow between calls.
UNIT_FIELDS = ("dataset_episodes", "pretrain_steps", "finetune_steps", "eval_episodes", "chunk_size",
               "entropy_threshold", "style_episodes", "style_max_epochs", "env_kwargs", "algo_kwargs",
               "onestep_kwargs", "finetune_kwargs", "online_seed_offset")


class RunPaths(records.RunPaths):
    """Where a Figure-2 run keeps its files, and the budget manifest that refuses to resume it under another."""

    NAME = "fig2"
    BUDGET = Fig2Budget
    FIELDS = UNIT_FIELDS


def finetune_overrides(budget: Fig2Budget) -> dict[str, Any]:
    """Phase-2 attributes of every fine-tuned arm: ``finetune_kwargs`` and one update per ``chunk_size`` env steps."""
    return {**budget.finetune_kwargs, "train_freq": budget.chunk_size, "gradient_steps": 1}  # same as default: the cadence


#: The stages of a run, in the order its report lists them
STAGES = ("datasets", "pretrain", "finetune", "evaluate", "style", "style_ablation")
#: The stages a seed's ``"style"`` part runs (:func:`experiments.fig2.units.run_all`); its ``"main"`` part runs the rest
STYLE_STAGES = ("style", "style_ablation")


def stage_sizes(budget: Fig2Budget) -> dict[str, float]:
    """The size of each stage of one seed, what its recorded seconds scale with."""
    n_evals = (len(MAIN_METHODS) + 2 + len(budget.delta_sweep) + len(budget.k_sweep) + int(budget.style_ablation)
               + 2 * len(budget.acting_variants()) + len(SAMPLED_METHODS) * int(budget.sampled_eval)
               + 2 * (budget.online_replicates - 1) * (1 + int(budget.sampled_eval)))  # both arms of further phases
    return {
        "datasets": budget.dataset_episodes,
        "pretrain": budget.pretrain_steps * len(budget.pretrain_ks),
        "finetune": budget.finetune_steps * 2 * budget.online_replicates,
        "evaluate": budget.eval_episodes * n_evals,
        "style": budget.style_episodes,
        "style_ablation": (budget.pretrain_steps + budget.finetune_steps) * int(budget.style_ablation),
    }


def estimate_seconds(budget: Fig2Budget, n_seeds: int,
                     reports: Sequence[Mapping[str, Any]] | None = None) -> dict[str, float]:
    """CPU seconds per stage of a run and ``"total"``, from the ``reports`` (default: the committed ones)."""
    reports = recorded("**/fig2.json") if reports is None else reports
    rates = seconds_per_size((stage, seconds, size * len(report["seeds"]))
                             for report in reports if report.get("seconds", {}).get("measured")
                             for stage, size in stage_sizes(Fig2Budget.from_dict(report["budget"])).items()
                             if (seconds := report["seconds"]["measured"].get(stage)) is not None)
    out = estimate(rates, {stage: n_seeds * size for stage, size in stage_sizes(budget).items()})
    return {**out, "total": sum(out.values())}


def estimate_wall_seconds(stages: Mapping[str, float], n_seeds: int, workers: int) -> float:
    """Wall time of a run of ``stages`` CPU seconds, its parts scheduled as :func:`~experiments.fig2.units.run_all` does."""
    style = sum(stages.get(name, 0.0) for name in STYLE_STAGES) / n_seeds
    main = stages["total"] / n_seeds - style
    return list_schedule_seconds([main] * n_seeds + [style] * n_seeds, workers)  # run_all's order
