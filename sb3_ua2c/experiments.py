"""Reproduction of the paper's Figure 2 on ``MixedTraffic-v0``, over several seeds (paper §4).

One command runs the four panels and the sweeps that go beyond the paper::

    python benchmarks/fig2.py                  # 5 seeds, full budget (estimate printed at start)
    python benchmarks/fig2.py --quick --seeds 1  # tiny budget, a smoke test (a minute or two)

Per seed ``s`` the runner does, building on :mod:`sb3_ua2c.offline` and :mod:`sb3_ua2c.pipeline`:

* (a), (b) **offline**: one dataset; the chunk policy (``chunk_size=k``) and the one-step
  baseline (``chunk_size=1``) are pre-trained on it with the same number of gradient steps and
  evaluated on the same scenarios (reward, cumulative jerk). The offline chunk policy executes
  its chunks in full (δ = inf): adaptive execution is the Phase-2 mechanism, compared in (c).
* (c) **online**: adaptive (finite δ) and fixed (δ = inf) execution, both fine-tuned from the
  SAME chunk checkpoint of (a) with the same number of online steps, evaluated on the same
  scenarios with their own execution rule.
* (d) **driving style**: a labelled slot dataset, the Transformer classifier of Eq. 5 and its
  evaluation on held-out episodes (:func:`sb3_ua2c.style.evaluate_style_classifier`); the panel
  shows the confusion matrix summed over seeds (rows inferred, columns ground truth).
* sweeps: δ (the fine-tuned adaptive checkpoint executed with several thresholds: mean executed
  length ``L_t`` vs reward), k (pre-training with several chunk lengths, same gradient budget)
  and the style context c_t (Eq. 6) appended to the observation vs not (own dataset, same
  pre-training and online budgets as the adaptive arm).

Every unit of work is a file, written atomically: the dataset ``<work>/seed<s>/dataset``, the
checkpoints ``<work>/seed<s>/*.zip`` and the per-seed raw results ``<raw>/seed<s>/*.json``.
A unit whose file exists is skipped, so an interrupted run resumes where it stopped and a second
call only rebuilds the report.

Relative changes. Rewards may be negative, so a relative change is taken with respect to the
magnitude of the baseline: ``100 · (new − base) / |base|`` (:func:`relative_change_pct`).
The headline figures apply it to the means over seeds; the table also gives the per-seed changes'
mean and 95% confidence interval. Confidence intervals are Student-t intervals over seeds
(:func:`t_confidence_interval`), ``mean ± t_{0.975, n−1} · sd / √n``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shlex
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sb3_ua2c.__main__ import json_object_arg
from sb3_ua2c.checks import check_int

#: The paper's Fig. 2 figures (one seed), in percent.
PAPER = {
    "offline_reward_gain_pct": 6.70,
    "offline_jerk_change_pct": -18.37,
    "online_reward_gain_pct": 13.17,
}
#: The comparison behind each of the paper's numbers (``comparisons`` key of ``fig2.json``).
CLAIM_COMPARISONS = {
    "offline_reward_gain_pct": "offline_reward",
    "offline_jerk_change_pct": "offline_jerk",
    "online_reward_gain_pct": "online_reward",
}
#: Metrics of :class:`sb3_ua2c.pipeline.EpisodeMetrics` aggregated per method.
METRICS = (
    "reward", "cumulative_jerk", "jerk_per_step", "collision", "merge_success", "mean_speed", "mean_executed_length",
)
#: fine-tuned arms whose Phase-2 training episodes are logged (``<raw>/online/<arm>.json``)
ONLINE_ARMS = ("fixed", "adaptive", "adaptive_style")
#: The four arms of Fig. 2 (a)-(c).
MAIN_METHODS = ("onestep", "chunk", "fixed", "adaptive")
#: Methods also evaluated with fresh candidate noise per replanning (``Fig2Budget.sampled_eval``).
SAMPLED_METHODS = ("onestep", "chunk", "chunk_adaptive", "fixed", "adaptive", "fixed_adaptive")
METHOD_LABELS = {
    "onestep": "one-step baseline (k=1)",
    "chunk": "chunk policy (offline, full chunks)",
    "chunk_adaptive": "chunk policy (offline, adaptive execution)",
    "fixed": "fixed chunks (δ=inf, online)",
    "adaptive": "adaptive chunks (online)",
    "fixed_adaptive": "fixed-trained checkpoint, adaptive execution",
    "adaptive_style": "adaptive chunks + style context c_t",
}
METHOD_LABELS.update({f"{m}_sampled": f"{METHOD_LABELS[m]}, sampled" for m in SAMPLED_METHODS})
#: Seed offsets: datasets, evaluation scenarios and style data never share a SUMO seed as long as
#: run seeds are < MAX_SEED, episodes per dataset < 10,000 and evaluation episodes <= 1,000.
DATASET_SEED_BASE = 1_000_000  # episode i of run seed s: 1_000_000 + 10_000 s + i
STYLE_SEED_BASE = 3_000_000  # episode i of run seed s: 3_000_000 + 10_000 s + i
EVAL_SEED_BASE = 2_000  # evaluate() resets episode i of seed e with 1000 * e + i -> 2_000_000 + 1000 s + i
MAX_SEED = 100


# ---------------------------------------------------------------------------------------------
# Configuration
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Fig2Budget:
    """Budget and hyperparameters of one Figure-2 run (per seed); an unknown key or a bad value
    raises ``ValueError`` naming it.

    :param dataset_episodes: offline episodes collected per seed (behaviour policy of
        :class:`~sb3_ua2c.offline.BehaviourConfig`)
    :param pretrain_steps: Phase-1 gradient steps, the same for every pre-trained arm
    :param finetune_steps: Phase-2 environment steps, the same for adaptive and fixed; both arms make
        one gradient step per ``chunk_size`` environment steps (the same number of updates, whatever
        the executed lengths)
    :param eval_episodes: evaluation episodes per method and seed (same scenarios for all methods)
    :param chunk_size: ``k`` of the chunk policy
    :param entropy_threshold: δ of the adaptive arm (Eq. 7); the fixed arm uses ``inf``
    :param style_episodes: episodes of the driving-style dataset per seed (>= 3: split by episode)
    :param style_max_epochs: epochs bound of the style classifier's training (early stopping)
    :param delta_sweep: thresholds δ at which the fine-tuned adaptive checkpoint is executed
    :param k_sweep: chunk lengths pre-trained for the k sweep (``1`` and ``chunk_size`` reuse
        the arms of panel (a))
    :param style_ablation: run the "adaptive + style context" arm
    :param elite_sweep: ``n_elite`` values (elite-mean execution, ``UA2C.set_n_elite``) at which the
        offline one-step and chunk checkpoints are also evaluated (full chunks)
    :param flow_sweep: Euler steps ``N`` of the sampler (``UA2C.set_flow_steps``) at which the same
        two checkpoints are also evaluated, with ``n_elite = 1`` and each value of ``elite_sweep``
    :param env_kwargs: ``MixedTraffic-v0`` keyword arguments (the same for every unit)
    :param algo_kwargs: extra UA2C constructor arguments of every pre-trained arm (the fine-tuned
        arms inherit them from their checkpoint), e.g. ``{"smooth_weight": 100.0}``
    :param onestep_kwargs: UA2C constructor arguments of the one-step baseline (k = 1, also the k
        sweep's k = 1) that replace those of ``algo_kwargs`` key by key, so that each arm can run
        at its own size, e.g. ``{"policy_kwargs": {"net_arch": [128, 128]}}`` next to a larger
        chunk actor in ``algo_kwargs``; empty = the same arguments as the chunk policy
    :param finetune_kwargs: UA2C attributes overridden for Phase 2 only, the same for every
        fine-tuned arm (e.g. ``{"smooth_weight": 100.0}`` or ``{"n_elite": 8}``; ``train_freq`` and ``gradient_steps``
        are set by the runner, see :func:`finetune_overrides`)
    :param online_seed_offset: Phase 2 of seed ``s`` runs with seed ``s + MAX_SEED · offset``
        (online scenarios, sampling noise, minibatches; the networks start from the same
        checkpoint): a replicate of the online phase on the same pre-trained checkpoints. 0 = the
        seed itself
    :param online_replicates: online phases per seed, all from the same pre-trained checkpoint: phase
        ``r`` runs with offset ``online_seed_offset + r`` (units ``adaptive_r<r>`` / ``fixed_r<r>``
        for ``r >= 1``). (c) pools the paired runs of every phase: one online phase moves a
        five-seed mean by 10-20 %, more than the paper's +13.17 %
    :param sampled_eval: also evaluate :data:`SAMPLED_METHODS` with fresh candidate noise at every
        replanning (``predict(deterministic=False)``, seeded per episode), the acting rule of the
        Phase-2 rollouts, into ``<method>_sampled``; the headline rows use the fixed noise of
        ``deterministic=True``
    """

    dataset_episodes: int = 200
    pretrain_steps: int = 6000
    finetune_steps: int = 10000
    eval_episodes: int = 20
    chunk_size: int = 5
    entropy_threshold: float = 0.0
    style_episodes: int = 400
    style_max_epochs: int = 40
    delta_sweep: tuple[float, ...] = (-0.5, 0.0, 0.25, 0.5, 1.0, math.inf)
    k_sweep: tuple[int, ...] = (1, 3, 5, 10)
    style_ablation: bool = True
    elite_sweep: tuple[int, ...] = (4, 8, 16)
    flow_sweep: tuple[int, ...] = (2,)
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    algo_kwargs: Mapping[str, Any] = field(default_factory=dict)
    onestep_kwargs: Mapping[str, Any] = field(default_factory=dict)
    finetune_kwargs: Mapping[str, Any] = field(default_factory=dict)
    online_seed_offset: int = 0
    online_replicates: int = 1
    sampled_eval: bool = True

    def __post_init__(self) -> None:
        for name in (
            "dataset_episodes",
            "pretrain_steps",
            "finetune_steps",
            "eval_episodes",
            "chunk_size",
            "style_max_epochs",
        ):
            check_int(f"Fig2Budget.{name}", getattr(self, name))
        check_int("Fig2Budget.style_episodes", self.style_episodes, low=3)
        check_int("Fig2Budget.online_seed_offset", self.online_seed_offset, low=0)
        check_int("Fig2Budget.online_replicates", self.online_replicates)
        for name, limit in (("dataset_episodes", 9_999), ("style_episodes", 9_999), ("eval_episodes", 1_000)):
            if getattr(self, name) > limit:
                raise ValueError(
                    f"Fig2Budget.{name} must be <= {limit} (seed ranges), got {getattr(self, name)!r}"
                )
        if (
            isinstance(self.entropy_threshold, bool)
            or not isinstance(self.entropy_threshold, int | float)
            or not math.isfinite(self.entropy_threshold)
        ):
            raise ValueError(
                f"Fig2Budget.entropy_threshold must be a finite number (the fixed arm is δ=inf), "
                f"got {self.entropy_threshold!r}"
            )
        deltas = tuple(float(d) for d in self.delta_sweep)
        if any(math.isnan(d) or d == -math.inf for d in deltas):
            raise ValueError(f"Fig2Budget.delta_sweep must hold numbers > -inf, got {self.delta_sweep!r}")
        ks = tuple(self.k_sweep)
        for k in ks:
            check_int("Fig2Budget.k_sweep", k)
        n_candidates = min(
            kwargs.get("n_candidates", 32) if isinstance(kwargs, Mapping) else 32
            for kwargs in (self.algo_kwargs, self.onestep_kwargs)
        )
        for m in self.elite_sweep:
            check_int("Fig2Budget.elite_sweep", m)
            if m > n_candidates:
                raise ValueError(f"Fig2Budget.elite_sweep holds {m}, more than the {n_candidates} candidates")
        for n in self.flow_sweep:
            check_int("Fig2Budget.flow_sweep", n)
        for name in ("style_ablation", "sampled_eval"):  # JSON bools only (the budget is written to JSON)
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"Fig2Budget.{name} must be a bool, got {getattr(self, name)!r}")
        for name in ("env_kwargs", "algo_kwargs", "onestep_kwargs", "finetune_kwargs"):
            if not isinstance(getattr(self, name), Mapping):
                raise ValueError(f"Fig2Budget.{name} must be a mapping, got {getattr(self, name)!r}")
        for name in ("algo_kwargs", "onestep_kwargs"):
            reserved = {"chunk_size", "entropy_threshold"} & set(getattr(self, name))
            if reserved:
                raise ValueError(
                    f"Fig2Budget.{name} must not set {sorted(reserved)}: they are Fig2Budget fields"
                )
        elites = {k: _policy_elite(self, k) for k in (1, self.chunk_size)}
        if elites[1] != elites[self.chunk_size]:  # (a) and (b) compare both arms acting by one rule
            raise ValueError(
                f"Fig2Budget.onestep_kwargs: the one-step baseline acts with n_elite={elites[1]} and the "
                f"chunk policy with n_elite={elites[self.chunk_size]}; (a) and (b) need the same acting rule"
            )
        reserved = {"chunk_size", "entropy_threshold", "train_freq", "gradient_steps"} & set(self.finetune_kwargs)
        if reserved:
            raise ValueError(
                f"Fig2Budget.finetune_kwargs must not set {sorted(reserved)}: the runner sets them"
            )
        object.__setattr__(self, "delta_sweep", tuple(sorted(set(deltas))))
        object.__setattr__(self, "k_sweep", tuple(sorted(set(int(k) for k in ks))))
        object.__setattr__(self, "elite_sweep", tuple(sorted(set(int(m) for m in self.elite_sweep))))
        object.__setattr__(self, "flow_sweep", tuple(sorted(set(int(n) for n in self.flow_sweep))))
        object.__setattr__(self, "entropy_threshold", float(self.entropy_threshold))
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))
        object.__setattr__(self, "algo_kwargs", dict(self.algo_kwargs))
        object.__setattr__(self, "onestep_kwargs", dict(self.onestep_kwargs))
        object.__setattr__(self, "finetune_kwargs", dict(self.finetune_kwargs))

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Fig2Budget:
        """Build from a mapping (e.g. JSON); an unknown key raises ``ValueError`` naming it."""
        unknown = set(values) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(
                f"unknown Fig2Budget key(s) {sorted(unknown)}; valid: {sorted(f.name for f in dataclasses.fields(cls))}"
            )
        values = dict(values)
        for name in ("delta_sweep", "k_sweep", "elite_sweep", "flow_sweep"):
            if name in values:
                values[name] = tuple(float(v) if name == "delta_sweep" else v for v in values[name])
        return cls(**values)

    def replace(self, **changes: Any) -> Fig2Budget:
        """A copy with ``changes`` applied (validated like :meth:`from_dict`)."""
        return Fig2Budget.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the fields (lists for the sweeps), the inverse of :meth:`from_dict`."""
        out = dataclasses.asdict(self)
        out["delta_sweep"] = list(self.delta_sweep)
        out["k_sweep"] = list(self.k_sweep)
        out["elite_sweep"] = list(self.elite_sweep)
        out["flow_sweep"] = list(self.flow_sweep)
        return out

    @property
    def default_elite(self) -> int:
        """``n_elite`` the pre-trained arms act with (their ``policy_kwargs``; 1 = best-of-S)."""
        return _policy_elite(self, self.chunk_size)

    @property
    def acting_variants(self) -> tuple[tuple[int | None, int], ...]:
        """``(flow_steps, n_elite)`` pairs of the acting sweep (``None`` = the checkpoint's ``N``):
        ``n_elite`` in :attr:`default_elite`, 1 and ``elite_sweep``, without
        ``(None, default_elite)``, which is how (a) and (b) act."""
        m0 = self.default_elite
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


def _policy_kwargs(kwargs: Mapping[str, Any]) -> Mapping[str, Any]:
    """``policy_kwargs`` of UA2C arguments ``kwargs`` (empty when unset or not a mapping: UA2C itself
    rejects the latter when the arm is built)."""
    policy_kwargs = kwargs.get("policy_kwargs") or {}
    return policy_kwargs if isinstance(policy_kwargs, Mapping) else {}


def _policy_elite(budget: Fig2Budget, k: int) -> int:
    """``policy_kwargs["n_elite"]`` of the arm with chunk length ``k`` (1 when unset)."""
    return int(_policy_kwargs(budget.arm_kwargs(k)).get("n_elite", 1))


#: Default budget: about two hours for 5 seeds on 2 cores (see :func:`estimate_seconds`). Each
#: offline arm at its better size by reward (the chunk policy's velocity field 3 × 512, the one-step
#: baseline's 128 × 2), every arm acting by the elite mean of 8 candidates, two online phases pooled
#: into (c); the k sweep stops at k = 5 to stay within the budget (k = 10 collapsed at 128 × 2).
FULL_BUDGET = Fig2Budget(
    k_sweep=(1, 3, 5),
    algo_kwargs={"policy_kwargs": {"net_arch": [512, 512, 512], "n_elite": 8}},
    onestep_kwargs={"policy_kwargs": {"net_arch": [128, 128], "n_elite": 8}},
    online_replicates=2,
)
#: ``--quick``: 4-second episodes and a handful of updates, for smoke tests and CI.
QUICK_BUDGET = Fig2Budget(
    dataset_episodes=3,
    pretrain_steps=8,
    finetune_steps=30,
    eval_episodes=1,
    style_episodes=6,
    style_max_epochs=2,
    delta_sweep=(0.0, math.inf),
    k_sweep=(1, 2, 3),
    elite_sweep=(2,),
    flow_sweep=(2,),
    chunk_size=3,
    env_kwargs={"time_limit": 4.0},
    algo_kwargs={"batch_size": 32},
    online_replicates=2,
)


@dataclass(frozen=True)
class CostModel:
    """Per-unit costs used to estimate a run's wall time, measured on a shared 2-core machine with
    one torch thread (torch 2.13 CPU, default UA2C networks, batch 256, 200-step episodes).

    :param collect_ms_per_step: behaviour-policy collection, per env step
    :param pretrain_ms_per_step: Phase-1 gradient step, part independent of the chunk length
    :param pretrain_ms_per_step_per_k: Phase-1 gradient step, per unit of chunk length (measured
        on 2026-11-23: k=1: 18 ms, k=3: 20 ms, k=5: 27 ms, k=10: 42 ms)
    :param finetune_ms_per_update: Phase-2 gradient step of the k=5 policy
    :param finetune_ms_per_env_step: Phase-2 env step excluding updates
    :param eval_ms_per_step: evaluation (replanning amortised), per env step
    :param style_ms_per_step: style-data collection, per env step
    :param style_s_per_epoch: style classifier training, per epoch of a 60-episode dataset
    :param style_context_factor: slowdown of env steps with the style wrapper
    :param adaptive_plan_length: mean ``L_t`` of the adaptive arm's Phase-2 rollouts (one replanning
        per L steps; the default runs executed 4.4-4.6 of k = 5 actions per plan: the adaptive arm
        fine-tuned in 74 s per seed against 70 s for the fixed arm at 128 × 2, 130 s against 120 s at
        3 × 512)
    :param plan_ms: one replanning during Phase 2
    :param update_ms_per_kweight: extra cost of a gradient step (Phase 1 and 2) per 1,000
        hidden-to-hidden weights of the velocity field beyond the default 128 × 2 (see
        :func:`velocity_field_weights`; measured on 2026-12-02 with one torch thread: 128 × 2 / 3 × 256 /
        3 × 512 took 13.4 / 19.2 / 32.4 ms per step at k = 1 and 25.5 / 29.8 / 41.8 ms at k = 5)
    :param plan_ms_per_kweight: the same for one replanning (measured 1.6 / 2.6 / 5.5 ms at k = 5)
    """

    collect_ms_per_step: float = 0.4
    pretrain_ms_per_step: float = 14.0
    pretrain_ms_per_step_per_k: float = 2.8
    finetune_ms_per_update: float = 20.0
    finetune_ms_per_env_step: float = 3.0
    eval_ms_per_step: float = 1.5
    style_ms_per_step: float = 0.3
    style_s_per_epoch: float = 0.05
    style_context_factor: float = 2.0
    adaptive_plan_length: float = 4.0
    plan_ms: float = 4.0
    update_ms_per_kweight: float = 0.032
    plan_ms_per_kweight: float = 0.008

    def pretrain_step_ms(self, k: int, extra_kweights: float = 0.0) -> float:
        """One Phase-1 gradient step of a k-step policy whose velocity field has ``extra_kweights``
        thousand hidden weights beyond the default (:func:`extra_kweights`)."""
        return self.pretrain_ms_per_step + k * self.pretrain_ms_per_step_per_k + extra_kweights * self.update_ms_per_kweight

    def replan_ms(self, extra_kweights: float = 0.0) -> float:
        """One replanning during Phase 2, for a velocity field ``extra_kweights`` thousand weights
        beyond the default."""
        return self.plan_ms + extra_kweights * self.plan_ms_per_kweight


def velocity_field_weights(kwargs: Mapping[str, Any]) -> int:
    """Hidden-to-hidden weights of the velocity field that UA2C arguments ``kwargs`` build
    (``policy_kwargs["net_arch"]``, default 128 × 2: 16,384), the part of its size that grows with
    the hidden widths."""
    from sb3_ua2c.policies import DEFAULT_NET_ARCH

    net_arch = list(_policy_kwargs(kwargs).get("net_arch") or DEFAULT_NET_ARCH)
    return sum(a * b for a, b in zip(net_arch[:-1], net_arch[1:], strict=False))


def extra_kweights(kwargs: Mapping[str, Any]) -> float:
    """Hidden weights of the velocity field built by UA2C arguments ``kwargs`` beyond the default
    128 × 2, in thousands (0 for smaller fields): what :class:`CostModel` scales with."""
    return max(0, velocity_field_weights(kwargs) - velocity_field_weights({})) / 1000


def estimate_seconds(budget: Fig2Budget, n_seeds: int, costs: CostModel | None = None) -> dict[str, float]:
    """Estimated CPU seconds of a run from measured per-unit costs (one worker = one core).

    :param budget: the run's budget
    :param n_seeds: number of seeds
    :param costs: per-unit costs (default :class:`CostModel`)
    :return: seconds per stage and ``"total"`` (summed over seeds, before resuming)
    """
    c = costs or CostModel()
    steps_per_episode = float(budget.env_kwargs.get("time_limit", 40.0)) / float(
        budget.env_kwargs.get("step_length", 0.2)
    )
    ms = 1e-3
    data = budget.dataset_episodes * steps_per_episode * c.collect_ms_per_step * ms

    def extra(k: int) -> float:  # the k-step arm's velocity-field weights beyond the default [thousands]
        return extra_kweights(budget.arm_kwargs(k))

    def pretrain_s(k: int) -> float:
        return budget.pretrain_steps * c.pretrain_step_ms(k, extra(k)) * ms

    pre = sum(pretrain_s(k) for k in budget.pretrain_ks)
    updates_scale = budget.algo_kwargs.get("batch_size", 256) / 256

    chunk_extra = extra(budget.chunk_size)

    def online(plan_length: float) -> float:  # one update per chunk_size env steps (both arms)
        per_step = (
            c.finetune_ms_per_env_step
            + c.replan_ms(chunk_extra) / plan_length
            + (c.finetune_ms_per_update * updates_scale + chunk_extra * c.update_ms_per_kweight) / budget.chunk_size
        )
        return budget.finetune_steps * per_step * ms

    fine = (online(c.adaptive_plan_length) + online(budget.chunk_size)) * budget.online_replicates
    n_evals = (
        len(MAIN_METHODS) + 2 + len(budget.delta_sweep) + len(budget.k_sweep) + int(budget.style_ablation)
        + 2 * len(budget.acting_variants) + len(SAMPLED_METHODS) * int(budget.sampled_eval)
        + 2 * (budget.online_replicates - 1) * (1 + int(budget.sampled_eval))  # both arms of each further phase
    )
    # a larger velocity field replans more slowly: chunk arms replan about every k steps, one-step arms every step
    eval_ms = c.eval_ms_per_step + (chunk_extra / budget.chunk_size + extra(1)) * c.plan_ms_per_kweight
    evals = n_evals * budget.eval_episodes * steps_per_episode * eval_ms * ms
    style = (
        budget.style_episodes * steps_per_episode * c.style_ms_per_step * ms
        + budget.style_max_epochs * c.style_s_per_epoch * budget.style_episodes / 60
    )
    ablation = 0.0
    if budget.style_ablation:
        ablation = (
            data * c.style_context_factor
            + pretrain_s(budget.chunk_size)
            + online(c.adaptive_plan_length)
        )
    stages = {
        "datasets": data,
        "pretrain": pre,
        "finetune": fine,
        "evaluate": evals,
        "style": style,
        "style_ablation": ablation,
    }
    out = {name: n_seeds * value for name, value in stages.items()}
    out["total"] = sum(out.values())
    return out


# ---------------------------------------------------------------------------------------------
# Statistics (pure)
# ---------------------------------------------------------------------------------------------
def student_t_two_sided_cdf(t: float, df: int) -> float:
    """``P(|T| <= t)`` for Student's t with integer ``df`` degrees of freedom, closed form of
    Abramowitz & Stegun 26.7.3-26.7.4 (θ = atan(t / √df)).

    :param t: the bound, >= 0
    :param df: degrees of freedom, >= 1
    """
    if isinstance(df, bool) or not isinstance(df, int | np.integer) or df < 1:
        raise ValueError(f"df must be an integer >= 1, got {df!r}")
    if not t >= 0:
        raise ValueError(f"t must be >= 0, got {t!r}")
    if math.isinf(t):
        return 1.0
    theta = math.atan(t / math.sqrt(df))
    s, c = math.sin(theta), math.cos(theta)
    if df % 2 == 1:
        total, term = 0.0, c  # cos θ (1 + 2/3 cos²θ + 2·4/(3·5) cos⁴θ + ...), df - 2 terms' powers
        for j in range(1, (df - 1) // 2 + 1):
            total += term
            term *= c * c * (2 * j) / (2 * j + 1)
        return (2.0 / math.pi) * (theta + s * total) if df > 1 else 2.0 * theta / math.pi
    total, term = 0.0, 1.0  # 1 + 1/2 cos²θ + 1·3/(2·4) cos⁴θ + ..., up to cos^{df-2}
    for j in range(1, df // 2 + 1):
        total += term
        term *= c * c * (2 * j - 1) / (2 * j)
    return s * total


def student_t_quantile(confidence: float, df: int) -> float:
    """Two-sided critical value ``t`` with ``P(|T| <= t) = confidence`` (bisection, 1e-10).

    :param confidence: in (0, 1), e.g. 0.95 (``t = 2.776`` for ``df = 4``)
    :param df: degrees of freedom, >= 1
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    lo, hi = 0.0, 1.0
    while student_t_two_sided_cdf(hi, df) < confidence:
        hi *= 2.0
    while hi - lo > 1e-10 * max(1.0, hi):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if student_t_two_sided_cdf(mid, df) < confidence else (lo, mid)
    return 0.5 * (lo + hi)


def t_confidence_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float]:
    """Mean and half-width of the Student-t confidence interval over seeds.

    ``half = t_{(1+c)/2, n-1} · s / √n`` with the sample standard deviation ``s`` (ddof = 1);
    with one value the half-width is NaN (no spread can be estimated).

    :param values: (n,) one number per seed, finite
    :param confidence: coverage, e.g. 0.95
    :return: ``(mean, half_width)``
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"values must be a non-empty 1-D sequence, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"values must be finite, got {x.tolist()}")
    mean = float(x.mean())
    if x.size == 1:
        return mean, math.nan
    return mean, student_t_quantile(confidence, x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)


def relative_change_pct(new: float, base: float) -> float:
    """``100 · (new − base) / |base|``: positive when ``new`` is larger, whatever the sign of
    ``base`` (rewards may be negative). NaN when ``base`` is 0.

    :param new: the method's value
    :param base: the baseline's value
    """
    if base == 0 or not (math.isfinite(new) and math.isfinite(base)):
        return math.nan
    return 100.0 * (new - base) / abs(base)


def compare(new: Sequence[float], base: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """Relative change of paired per-seed values.

    :param new: (n,) the method's per-seed means
    :param base: (n,) the baseline's per-seed means, same seed order
    :return: ``change_pct`` (of the means over seeds, the headline figure), ``per_seed_pct``,
        and the t interval of the per-seed changes (``per_seed_mean_pct``, ``per_seed_ci95_pct``)
    """
    new_a, base_a = np.asarray(new, dtype=np.float64), np.asarray(base, dtype=np.float64)
    if new_a.shape != base_a.shape or new_a.ndim != 1 or new_a.size == 0:
        raise ValueError(
            f"new and base must be equal-length 1-D sequences, got {new_a.shape} and {base_a.shape}"
        )
    per_seed = [relative_change_pct(float(n), float(b)) for n, b in zip(new_a, base_a, strict=True)]
    finite = [p for p in per_seed if math.isfinite(p)]
    mean, half = t_confidence_interval(finite, confidence) if finite else (math.nan, math.nan)
    return {
        "change_pct": relative_change_pct(float(new_a.mean()), float(base_a.mean())),
        "per_seed_pct": per_seed,
        "per_seed_mean_pct": mean,
        "per_seed_ci95_pct": half,
    }


# ---------------------------------------------------------------------------------------------
# Units of work (each one a file; skipped when the file exists)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunPaths:
    """Where a run keeps its files.

    :param out: report directory (``fig2.md``, ``fig2.json``, PNG panels)
    :param raw: per-seed raw results (small JSON files, worth keeping with the report)
    :param work: datasets and checkpoints (large; not part of the report)
    """

    out: Path
    raw: Path
    work: Path

    @classmethod
    def under(
        cls,
        out: str | os.PathLike,
        raw: str | os.PathLike | None = None,
        work: str | os.PathLike | None = None,
    ) -> RunPaths:
        """Default layout: ``<out>/fig2_raw`` and ``<out>/fig2_work`` unless given."""
        out = Path(out)
        return cls(out, Path(raw) if raw else out / "fig2_raw", Path(work) if work else out / "fig2_work")

    def seed_work(self, seed: int) -> Path:
        return self.work / f"seed{seed}"

    def seed_raw(self, seed: int) -> Path:
        return self.raw / f"seed{seed}"


def delta_name(delta: float) -> str:
    """File-name-safe label of a threshold: ``0.5 -> "0.5"``, ``-1 -> "m1"``, ``inf -> "inf"``."""
    return "inf" if math.isinf(delta) else f"{delta:g}".replace("-", "m")


def replicate_name(arm: str, replicate: int) -> str:
    """Unit name of a fine-tuned arm in online phase ``replicate``: ``("fixed", 0) -> "fixed"``,
    ``("fixed", 2) -> "fixed_r2"`` (see ``Fig2Budget.online_replicates``)."""
    return arm if replicate == 0 else f"{arm}_r{replicate}"


def sampled_name(method: str) -> str:
    """Raw-result name of ``method`` evaluated with fresh candidate noise: ``"chunk"`` -> ``"chunk_sampled"``."""
    return f"{method}_sampled"


def acting_name(arm: str, flow_steps: int | None, n_elite: int, default_elite: int = 1) -> str:
    """Method name of an arm evaluated with another acting rule: ``("chunk", 2, 8) -> "chunk_flow2_elite8"``,
    ``("onestep", None, 8) -> "onestep_elite8"`` (``None`` = the checkpoint's Euler steps; ``n_elite``
    is named unless it is the checkpoints' ``default_elite``: ``("chunk", None, 1, 8) -> "chunk_elite1"``)."""
    elite = "" if n_elite == default_elite else f"_elite{n_elite}"
    return arm + ("" if flow_steps is None else f"_flow{flow_steps}") + elite


def command_line(prog: str, argv: Sequence[str]) -> str:
    """The invoking command as a shell line: ``prog`` then the arguments, quoted where needed."""
    return " ".join([prog, *map(shlex.quote, argv)])


class UnitLog(list):
    """Names of the units run, in order, and their wall-clock seconds (``seconds[name]``)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: dict[str, float] = {}

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        """Record unit ``name`` and the time the ``with`` block takes (only if it completes)."""
        start = time.perf_counter()
        yield
        self.append(name)
        self.seconds[name] = time.perf_counter() - start


def _dataset(
    path: Path,
    n_episodes: int,
    seed: int,
    env_kwargs: dict[str, Any],
    style_classifier: str | None,
    log: UnitLog,
    unit: str,
):
    """Load the dataset at ``path``, or collect it (unit ``unit``) when missing or damaged."""
    from sb3_ua2c.offline import METADATA_FILE, OfflineDatasetError, collect_dataset, load_dataset

    if (path / METADATA_FILE).is_file():
        try:
            return load_dataset(path)
        except OfflineDatasetError:
            pass  # damaged: collect again
    with log.timed(unit):
        return collect_dataset(
            path,
            n_episodes,
            env_kwargs=env_kwargs,
            style_classifier=style_classifier,
            seed=seed,
            overwrite=True,
        )


def _evaluation(
    raw: Path,
    method: str,
    checkpoint: Path,
    seed: int,
    budget: Fig2Budget,
    settings: dict[str, Any],
    entropy_threshold: float | None,
    log: UnitLog,
    n_elite: int | None = None,
    flow_steps: int | None = None,
    deterministic: bool = True,
) -> None:
    """Evaluate ``checkpoint`` on seed ``seed``'s scenarios into ``<raw>/<method>.json`` unless it exists
    (``deterministic``: fixed candidate noise, see :func:`sb3_ua2c.pipeline.evaluate`)."""
    from sb3_ua2c.pipeline import evaluate, summarize, write_json

    path = raw / f"{method}.json"
    if path.is_file():
        return
    with log.timed(f"seed{seed}/evaluate/{method}"):
        episodes = evaluate(
            checkpoint,
            n_episodes=budget.eval_episodes,
            seeds=(EVAL_SEED_BASE + seed,),
            env_settings_=settings,
            entropy_threshold=entropy_threshold,
            n_elite=n_elite,
            flow_steps=flow_steps,
            deterministic=deterministic,
        )
        write_json(
            path,
            {
                "method": method,
                "seed": seed,
                "checkpoint": checkpoint.name,
                "entropy_threshold": None
                if entropy_threshold is None
                else delta_name(float(entropy_threshold)),
                "eval_seed": EVAL_SEED_BASE + seed,
                "n_elite": n_elite,
                "flow_steps": flow_steps,
                "deterministic": deterministic,
                "summary": summarize(episodes),
                "episodes": episodes,
            },
        )


def finetune_overrides(budget: Fig2Budget) -> dict[str, Any]:
    """Phase-2 update cadence of every fine-tuned arm: one gradient step per ``chunk_size`` env steps.

    UA2C's default (one update per plan) would give the adaptive arm, whose plans are shorter,
    up to ``k`` times the updates of the fixed arm for the same environment steps. The budget's
    ``finetune_kwargs`` come on top.
    """
    return {**budget.finetune_kwargs, "train_freq": budget.chunk_size, "gradient_steps": 1}


class SeedBusyError(RuntimeError):
    """Another process is running the same seed in the same work directory."""


@contextmanager
def seed_lock(work: Path) -> Iterator[None]:
    """Hold an exclusive lock on a seed's work directory (``<work>/.lock``, ``flock``) while inside.

    Two ``fig2`` processes on one work directory (e.g. a second one started with ``--seed-list``)
    would otherwise train the same unit at once and write the same files. The lock dies with its
    process, so an interrupted run leaves nothing to clean up.

    On a platform without ``fcntl`` (Windows) there is no lock: do not start two runs on one
    work directory there.

    :param work: the seed's work directory (must exist)
    :raises SeedBusyError: if another open lock holds it, naming the directory and the holder's pid
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    with open(work / ".lock", "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise SeedBusyError(
                f"{work} is in use by another fig2 process (pid {holder}); wait for it or use "
                "another --work directory"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def run_seed(seed: int, budget: Fig2Budget, paths: RunPaths) -> list[str]:
    """Run (or resume) every unit of one seed; return the names of the units actually executed.

    The wall-clock seconds of every unit run are merged into ``<work>/seed<s>/unit_seconds.json``
    (measured cost of the run, next to :func:`estimate_seconds`). The seed's work directory is
    locked meanwhile (:func:`seed_lock`).

    :param seed: the seed (datasets, networks, online env, evaluation scenarios derive from it)
    :param budget: the run's budget
    :param paths: the run's directories
    """
    import torch

    torch.set_num_threads(1)
    work, raw = paths.seed_work(seed), paths.seed_raw(seed)
    work.mkdir(parents=True, exist_ok=True)
    raw.mkdir(parents=True, exist_ok=True)
    log = UnitLog()
    with seed_lock(work):
        try:
            _run_seed_units(seed, budget, work, raw, log)
        finally:  # also on an interruption: the finished units' times are kept
            _merge_seconds(work / "unit_seconds.json", log.seconds)
    return list(log)


def _merge_seconds(path: Path, seconds: Mapping[str, float]) -> None:
    from sb3_ua2c.pipeline import write_json

    if not seconds:
        return
    old = json.loads(path.read_text()) if path.is_file() else {}
    write_json(path, {**old, **seconds})


def _run_seed_units(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> None:
    """The units of :func:`run_seed`, in dependency order."""
    from sb3_ua2c.pipeline import env_settings, finetune, pretrain

    env_kwargs = dict(budget.env_kwargs)
    ds = _dataset(
        work / "dataset",
        budget.dataset_episodes,
        DATASET_SEED_BASE + 10_000 * seed,
        env_kwargs,
        None,
        log,
        f"seed{seed}/dataset",
    )
    settings = env_settings(ds)

    def pretrained(k: int, dataset: Any, name: str) -> Path:
        path = work / f"{name}.zip"
        if not path.is_file():
            with log.timed(f"seed{seed}/pretrain/{name}"):
                pretrain(dataset, path, budget.pretrain_steps, seed=seed, algo_kwargs=budget.arm_kwargs(k))
        return path

    def finetuned(start: Path, dataset: Any, name: str, delta: float, replicate: int = 0) -> Path:
        path, monitor = work / f"{name}.zip", work / f"{name}.monitor.csv"
        if not path.is_file():
            with log.timed(f"seed{seed}/finetune/{name}"):
                finetune(
                    start, path, budget.finetune_steps, dataset=dataset, entropy_threshold=delta,
                    seed=seed + MAX_SEED * (budget.online_seed_offset + replicate),
                    algo_overrides=finetune_overrides(budget), monitor_file=monitor,
                )
        _online_episodes(raw / "online" / f"{name}.json", monitor)
        return path

    # (a), (b) and the k sweep: same data, same gradient budget
    ckpt = {k: pretrained(k, ds, f"pretrain_k{k}") for k in budget.pretrain_ks}
    _evaluation(raw, "onestep", ckpt[1], seed, budget, settings, None, log)
    _evaluation(raw, "chunk", ckpt[budget.chunk_size], seed, budget, settings, math.inf, log)
    _evaluation(
        raw, "chunk_adaptive", ckpt[budget.chunk_size], seed, budget, settings, budget.entropy_threshold, log
    )
    for k in budget.k_sweep:
        _evaluation(raw, f"k{k}", ckpt[k], seed, budget, settings, math.inf, log)
    default_elite = budget.default_elite
    for n, m in budget.acting_variants:  # other acting rules for the same two checkpoints
        for arm, k in (("onestep", 1), ("chunk", budget.chunk_size)):
            delta = None if k == 1 else math.inf
            name = acting_name(arm, n, m, default_elite)
            _evaluation(raw, name, ckpt[k], seed, budget, settings, delta, log, m, n)
    # (c): both from the same chunk checkpoint, same online budget
    adaptive = finetuned(ckpt[budget.chunk_size], ds, "adaptive", budget.entropy_threshold)
    fixed = finetuned(ckpt[budget.chunk_size], ds, "fixed", math.inf)
    _evaluation(raw, "adaptive", adaptive, seed, budget, settings, budget.entropy_threshold, log)
    _evaluation(raw, "fixed", fixed, seed, budget, settings, math.inf, log)
    # the execution rule alone: the fixed arm's checkpoint executed with adaptive chunks
    _evaluation(raw, "fixed_adaptive", fixed, seed, budget, settings, budget.entropy_threshold, log)
    for delta in budget.delta_sweep:
        _evaluation(raw, f"delta_{delta_name(delta)}", adaptive, seed, budget, settings, delta, log)
    if budget.sampled_eval:  # the same checkpoints acting with fresh candidate noise, as in Phase 2
        k, delta = budget.chunk_size, budget.entropy_threshold
        sampled = {
            "onestep": (ckpt[1], None), "chunk": (ckpt[k], math.inf), "chunk_adaptive": (ckpt[k], delta),
            "fixed": (fixed, math.inf), "adaptive": (adaptive, delta), "fixed_adaptive": (fixed, delta),
        }
        for method in SAMPLED_METHODS:
            checkpoint, threshold = sampled[method]
            _evaluation(
                raw, sampled_name(method), checkpoint, seed, budget, settings, threshold, log, deterministic=False
            )
    # (d): driving-style inference
    classifier = _style_unit(seed, budget, work, raw, log)
    # beyond the paper: the style context c_t appended to the observation (Eq. 6)
    if budget.style_ablation:
        ds_style = _dataset(
            work / "dataset_style",
            budget.dataset_episodes,
            DATASET_SEED_BASE + 10_000 * seed,
            env_kwargs,
            str(classifier.resolve()),
            log,
            f"seed{seed}/dataset_style",
        )
        pre_style = pretrained(budget.chunk_size, ds_style, "pretrain_style")
        fine_style = finetuned(pre_style, ds_style, "adaptive_style", budget.entropy_threshold)
        _evaluation(
            raw,
            "adaptive_style",
            fine_style,
            seed,
            budget,
            env_settings(ds_style),
            budget.entropy_threshold,
            log,
        )
    # more online phases from the same checkpoint, pooled into (c) (the first one is above)
    for r in range(1, budget.online_replicates):
        for arm, delta in (("adaptive", budget.entropy_threshold), ("fixed", math.inf)):
            name = replicate_name(arm, r)
            tuned = finetuned(ckpt[budget.chunk_size], ds, name, delta, r)
            _evaluation(raw, name, tuned, seed, budget, settings, delta, log)
            if budget.sampled_eval:
                _evaluation(raw, sampled_name(name), tuned, seed, budget, settings, delta, log, deterministic=False)


def _online_episodes(path: Path, monitor: Path) -> None:
    """Copy the Phase-2 training episodes (return, length, collision; not the wall times) of one arm from its
    Monitor log into the raw results, unless done (or the log is missing: a run of an earlier version)."""
    from sb3_ua2c.pipeline import read_monitor, write_json

    if path.is_file() or not monitor.is_file():
        return
    episodes = [{"reward": e["r"], "length": int(e["l"]), "collision": bool(e["collision"])} for e in read_monitor(monitor)]
    write_json(path, {"episodes": episodes})


def _style_unit(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> Path:
    """Style data, classifier (Eq. 5) and its held-out evaluation of one seed; returns the classifier path."""
    from sb3_ua2c import style
    from sb3_ua2c.pipeline import write_json

    data_path, model_path, result_path = (
        work / "style_data.npz",
        work / "style_classifier.pt",
        raw / "style.json",
    )
    if data_path.is_file():
        data = style.StyleDataset.load(data_path)
    else:
        with log.timed(f"seed{seed}/style/collect"):
            data = style.collect_style_dataset(
                budget.style_episodes,
                seed=STYLE_SEED_BASE + 10_000 * seed,
                env_kwargs=dict(budget.env_kwargs),
                progress_bar=False,
            )
            tmp = data_path.with_name(".style_data.tmp.npz")
            data.save(tmp)
            os.replace(tmp, data_path)
    if model_path.is_file():
        model = style.DrivingStyleClassifier.load(model_path)
    else:
        with log.timed(f"seed{seed}/style/train"):
            model, _ = style.train_style_classifier(
                data, train_config={"max_epochs": budget.style_max_epochs, "seed": seed}, progress_bar=False
            )
            tmp = model_path.with_name(".style_classifier.tmp.pt")
            model.save(tmp)
            os.replace(tmp, model_path)
    if not result_path.is_file():
        with log.timed(f"seed{seed}/style/evaluate"):
            write_json(result_path, {"seed": seed, **style.evaluate_style_classifier(model, data)})
    return model_path


#: Budget fields that change what an existing unit holds; the sweeps may grow between calls.
UNIT_FIELDS = (
    "dataset_episodes",
    "pretrain_steps",
    "finetune_steps",
    "eval_episodes",
    "chunk_size",
    "entropy_threshold",
    "style_episodes",
    "style_max_epochs",
    "env_kwargs",
    "algo_kwargs",
    "onestep_kwargs",
    "finetune_kwargs",
    "online_seed_offset",
)
MANIFEST = "fig2_budget.json"


def check_manifest(paths: RunPaths, budget: Fig2Budget) -> Fig2Budget | None:
    """Refuse to resume a run made with another budget (its units would be silently reused).

    The first call records the budget in ``<work>/fig2_budget.json``; later calls must agree on
    :data:`UNIT_FIELDS` (the δ and k sweeps and the style ablation may change: they only add
    units).

    :return: the recorded budget, or ``None`` on the first call
    :raises ValueError: naming the fields that differ
    """
    recorded = read_manifest(paths)
    if recorded is None:
        return None
    differ = [name for name in UNIT_FIELDS if getattr(recorded, name) != getattr(budget, name)]
    if differ:
        details = ", ".join(
            f"{n}: recorded {getattr(recorded, n)!r}, now {getattr(budget, n)!r}" for n in differ
        )
        raise ValueError(
            f"the run in {paths.work} was made with another budget ({details}); "
            "pass the same budget to resume it, or another --out/--work to start a new run"
        )
    return recorded


def read_manifest(paths: RunPaths) -> Fig2Budget | None:
    """The budget recorded by the last call on ``paths`` (``None`` if there is none)."""
    path = paths.work / MANIFEST
    if not path.is_file():
        return None
    try:
        return Fig2Budget.from_dict(json.loads(path.read_text()))
    except (json.JSONDecodeError, TypeError, ValueError) as exc:
        raise ValueError(f"{path} is not a Fig2Budget record: {exc}") from exc


def write_manifest(paths: RunPaths, budget: Fig2Budget) -> None:
    from sb3_ua2c.pipeline import write_json

    write_json(paths.work / MANIFEST, strict_json(budget.to_dict()))


def measured_seconds(paths: RunPaths, seeds: Sequence[int]) -> dict[str, float]:
    """Wall-clock seconds of the units run so far, by the stages of :func:`estimate_seconds`.

    :param paths: the run's directories (reads ``<work>/seed<s>/unit_seconds.json``)
    :param seeds: the seeds to count
    :return: seconds per stage and ``"total"`` (stages without a record are absent)
    """
    out: dict[str, float] = {}
    for s in seeds:
        path = paths.seed_work(s) / "unit_seconds.json"
        if not path.is_file():
            continue
        for name, seconds in json.loads(path.read_text()).items():
            parts = name.split("/")  # seed<s>/<stage>[/<what>]
            if name.endswith("_style"):
                stage = "style_ablation"
            else:
                stage = {
                    "dataset": "datasets",
                    "pretrain": "pretrain",
                    "finetune": "finetune",
                    "evaluate": "evaluate",
                    "style": "style",
                }.get(parts[1], parts[1])
            out[stage] = out.get(stage, 0.0) + float(seconds)
    if out:
        out["total"] = sum(out.values())
    return out


def _run_seed_worker(args: tuple[int, dict[str, Any], RunPaths]) -> list[str]:
    seed, budget, paths = args
    return run_seed(seed, Fig2Budget.from_dict(budget), paths)


def run_all(
    seeds: Sequence[int], budget: Fig2Budget, paths: RunPaths, workers: int = 1, printer: Any = print
) -> list[str]:
    """Run (or resume) every seed, ``workers`` seeds at a time in separate processes (one SUMO
    simulation per process); ``workers=1`` runs in this process.

    :return: the units executed, over all seeds
    """
    check_int("Fig2Budget.workers", workers)
    check_manifest(paths, budget)
    write_manifest(paths, budget)
    executed: list[str] = []
    if workers == 1 or len(seeds) == 1:
        for s in seeds:
            t0 = time.perf_counter()
            units = run_seed(s, budget, paths)
            printer(f"seed {s}: {len(units)} unit(s) run in {time.perf_counter() - t0:.0f} s")
            executed += units
        return executed
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
        jobs = [(s, budget.to_dict(), paths) for s in seeds]
        for s, units in zip(seeds, pool.map(_run_seed_worker, jobs), strict=True):
            printer(f"seed {s}: {len(units)} unit(s) run")
            executed += units
    return executed


# ---------------------------------------------------------------------------------------------
# Aggregation and report
# ---------------------------------------------------------------------------------------------
def load_raw(paths: RunPaths, seeds: Sequence[int]) -> dict[str, dict[int, dict[str, Any]]]:
    """Per-seed raw results: ``{method: {seed: summary}}`` plus ``"style"`` (evaluation dicts)."""
    out: dict[str, dict[int, dict[str, Any]]] = {}
    for s in seeds:
        folder = paths.seed_raw(s)
        if not folder.is_dir():
            raise FileNotFoundError(f"no raw results for seed {s} in {folder}")
        for f in sorted(folder.glob("*.json")):
            payload = json.loads(f.read_text())
            out.setdefault(f.stem, {})[s] = payload if f.stem == "style" else payload["summary"]
        for f in sorted((folder / "online").glob("*.json")):
            out.setdefault(f"online/{f.stem}", {})[s] = json.loads(f.read_text())
    return out


def online_curve(
    episodes_per_seed: Sequence[Sequence[Mapping[str, Any]]], total_steps: int, n_bins: int = 10
) -> dict[str, list[float]]:
    """Learning curve of one arm: the mean return of the episodes that end in each of ``n_bins`` equal
    windows of the ``total_steps`` online steps, averaged over seeds (NaN where no episode ended)."""
    edges = np.linspace(0, total_steps, n_bins + 1)
    per_seed = []
    for episodes in episodes_per_seed:
        ends = np.cumsum([e["length"] for e in episodes])
        rewards = np.array([e["reward"] for e in episodes], dtype=float)
        which = np.clip(np.searchsorted(edges, ends, side="left") - 1, 0, n_bins - 1)
        per_seed.append(
            [float(rewards[which == b].mean()) if np.any(which == b) else math.nan for b in range(n_bins)]
        )
    values = np.array(per_seed, dtype=float).reshape(-1, n_bins)  # (seeds, bins)
    seen = np.isfinite(values).sum(axis=0)
    curve = np.where(seen > 0, np.nansum(values, axis=0) / np.maximum(seen, 1), np.nan)
    return {"steps": [float(x) for x in edges[1:]], "reward": [float(x) for x in curve]}


def online_phase_stats(episodes: Sequence[Mapping[str, Any]], last_fraction: float = 0.25) -> dict[str, float]:
    """Phase-2 training episodes of one arm and seed: mean return and collision rate over all of them and
    over the last ``last_fraction`` (at least one episode), and their number."""
    if not episodes:
        return {"reward": math.nan, "reward_last": math.nan, "collision": math.nan, "episodes": 0}
    last = episodes[-max(1, int(round(last_fraction * len(episodes)))) :]
    return {
        "reward": float(np.mean([e["reward"] for e in episodes])),
        "reward_last": float(np.mean([e["reward"] for e in last])),
        "collision": float(np.mean([e["collision"] for e in episodes])),
        "episodes": len(episodes),
    }


def _stats(per_seed: Mapping[int, Mapping[str, Any]], seeds: Sequence[int]) -> dict[str, Any]:
    out: dict[str, Any] = {"seeds": list(seeds)}
    for key in METRICS:  # a key missing from the raw data of an earlier version counts as NaN
        values = [float(per_seed[s].get(key, math.nan)) for s in seeds]
        finite = [v for v in values if math.isfinite(v)]
        mean, half = t_confidence_interval(finite) if finite else (math.nan, math.nan)
        out[key] = {"mean": mean, "ci95": half, "per_seed": values}
    return out


def aggregate(
    raw: Mapping[str, Mapping[int, Mapping[str, Any]]], seeds: Sequence[int], budget: Fig2Budget
) -> dict[str, Any]:
    """Everything ``fig2.json`` holds, computed from the per-seed raw results only.

    :param raw: output of :func:`load_raw`
    :param seeds: the seeds to aggregate (all must be present for every method)
    :param budget: the run's budget (recorded, and it names the sweep arms)
    """
    seeds = list(seeds)
    missing = [m for m in MAIN_METHODS if m not in raw or any(s not in raw[m] for s in seeds)]
    if missing:
        raise ValueError(f"raw results incomplete for method(s) {missing} and seeds {seeds}")
    methods = {
        m: _stats(raw[m], seeds)
        for m in raw
        if m != "style" and not m.startswith("online/") and all(s in raw[m] for s in seeds)
    }

    def per_seed(method: str, key: str) -> list[float]:
        return methods[method][key]["per_seed"]

    # online phases complete for every seed; (c) pools their paired runs
    phases = [
        r for r in range(budget.online_replicates)
        if all(replicate_name(arm, r) in methods for arm in ("adaptive", "fixed"))
    ]
    online_phases = _online_phases(raw, methods, seeds, phases)
    offline_reward = compare(per_seed("chunk", "reward"), per_seed("onestep", "reward"))
    offline_jerk = compare(per_seed("chunk", "cumulative_jerk"), per_seed("onestep", "cumulative_jerk"))
    online_reward = compare(online_phases["adaptive"]["per_seed"], online_phases["fixed"]["per_seed"])
    result: dict[str, Any] = {
        "offline_reward_gain_pct": offline_reward["change_pct"],
        "offline_jerk_change_pct": offline_jerk["change_pct"],
        "online_reward_gain_pct": online_reward["change_pct"],
        "comparisons": {
            "offline_reward": offline_reward,
            "offline_jerk": offline_jerk,
            "online_reward": online_reward,
        },
        "paper": dict(PAPER),
        "relative_change_definition": "100 * (method - baseline) / |baseline|, on the means over seeds",
        "methods": methods,
        "seeds": seeds,
        "budget": budget.to_dict(),
        "online_phases": online_phases,
    }
    if "style" in raw and all(s in raw["style"] for s in seeds):
        styles = [raw["style"][s] for s in seeds]
        macro = [float(r["macro_accuracy"]) for r in styles]
        mean, half = t_confidence_interval(macro)
        matrix = np.sum([np.asarray(r["confusion_matrix"], dtype=np.int64) for r in styles], axis=0)
        result["style_macro_accuracy"] = mean
        result["style"] = {
            "macro_accuracy": {"mean": mean, "ci95": half, "per_seed": macro},
            "accuracy_per_seed": [float(r["accuracy"]) for r in styles],
            "baseline_macro_accuracy_per_seed": [
                float(r["baseline"]["macro_accuracy"]) for r in styles if "baseline" in r
            ],
            "confusion_matrix": matrix.tolist(),
            "confusion_matrix_layout": "rows = inferred style, columns = ground truth, summed over seeds",
            "classes": styles[0]["classes"],
        }
    else:
        result["style_macro_accuracy"] = math.nan
    result["delta_sweep"] = [
        {
            "delta": d,
            "method": f"delta_{delta_name(d)}",
            **{
                k: methods[f"delta_{delta_name(d)}"][k]
                for k in ("reward", "mean_executed_length", "cumulative_jerk")
            },
        }
        for d in budget.delta_sweep
        if f"delta_{delta_name(d)}" in methods
    ]
    result["k_sweep"] = [
        {
            "k": k,
            "method": f"k{k}",
            **{key: methods[f"k{k}"][key] for key in ("reward", "cumulative_jerk", "collision")},
        }
        for k in budget.k_sweep
        if f"k{k}" in methods
    ]
    result["acting_sweep"] = []
    from sb3_ua2c.ua2c import UA2CConfig

    default_n = int(budget.algo_kwargs.get("flow_steps", UA2CConfig.flow_steps))
    default_elite = budget.default_elite
    result["acting_default"] = {"flow_steps": default_n, "n_elite": default_elite}
    for n, m in budget.acting_variants:  # other acting rules for the offline checkpoints
        arms = {arm: acting_name(arm, n, m, default_elite) for arm in ("onestep", "chunk")}
        if not all(name in methods for name in arms.values()):
            continue
        row: dict[str, Any] = {"flow_steps": default_n if n is None else n, "n_elite": m}
        for arm, name in arms.items():
            row[arm] = {key: methods[name][key] for key in ("reward", "cumulative_jerk", "jerk_per_step", "collision")}
        row["jerk_change"] = compare(per_seed(arms["chunk"], "cumulative_jerk"), per_seed(arms["onestep"], "cumulative_jerk"))
        row["reward_change"] = compare(per_seed(arms["chunk"], "reward"), per_seed(arms["onestep"], "reward"))
        result["acting_sweep"].append(row)
    if "fixed_adaptive" in methods:  # the execution rule alone, on the fixed arm's checkpoint
        result["comparisons"]["online_execution_rule"] = compare(
            per_seed("fixed_adaptive", "reward"), per_seed("fixed", "reward")
        )
    if "chunk_adaptive" in methods:  # beyond the paper: the offline chunk policy with Eq. 7 execution
        result["comparisons"]["offline_reward_chunk_adaptive"] = compare(
            per_seed("chunk_adaptive", "reward"), per_seed("onestep", "reward")
        )
        result["comparisons"]["offline_jerk_chunk_adaptive"] = compare(
            per_seed("chunk_adaptive", "cumulative_jerk"), per_seed("onestep", "cumulative_jerk")
        )
    online = {
        arm: [online_phase_stats(raw[f"online/{arm}"][s]["episodes"]) for s in seeds]
        for arm in ONLINE_ARMS
        if f"online/{arm}" in raw and all(s in raw[f"online/{arm}"] for s in seeds)
    }
    if online:
        result["online_phase"] = {}
        for arm, rows in online.items():
            stats: dict[str, Any] = {}
            for key in ("reward", "reward_last", "collision", "episodes"):
                values = [r[key] for r in rows]
                mean, half = t_confidence_interval(values)
                stats[key] = {"mean": mean, "ci95": half, "per_seed": values}
            stats["curve"] = online_curve([raw[f"online/{arm}"][s]["episodes"] for s in seeds], budget.finetune_steps)
            result["online_phase"][arm] = stats
    episodes = result["online_phases"]["training_episodes"]
    if episodes:  # (c') and (c''), pooled over the online phases like (c)
        result["comparisons"]["online_phase_reward"] = compare(episodes["adaptive"]["reward"], episodes["fixed"]["reward"])
        result["comparisons"]["online_phase_reward_last"] = compare(
            episodes["adaptive"]["reward_last"], episodes["fixed"]["reward_last"]
        )
    if {"chunk", "onestep"} <= set(methods) and all(
        math.isfinite(v) for m in ("chunk", "onestep") for v in per_seed(m, "jerk_per_step")
    ):
        result["comparisons"]["offline_jerk_per_step"] = compare(
            per_seed("chunk", "jerk_per_step"), per_seed("onestep", "jerk_per_step")
        )
    if all(sampled_name(m) in methods for m in MAIN_METHODS):  # (a)-(c) with fresh candidate noise
        sampled = {
            "offline_reward": ("chunk", "onestep", "reward"),
            "offline_jerk": ("chunk", "onestep", "cumulative_jerk"),
            "online_reward": ("adaptive", "fixed", "reward"),
            "offline_jerk_per_step": ("chunk", "onestep", "jerk_per_step"),
            "online_execution_rule": ("fixed_adaptive", "fixed", "reward"),
        }
        for key, (new, base, metric) in sampled.items():
            names = (sampled_name(new), sampled_name(base))
            if key == "online_reward":  # pooled over the online phases, like (c)
                if {"adaptive_sampled", "fixed_sampled"} <= set(online_phases):
                    result["comparisons"][f"{key}_sampled"] = compare(
                        online_phases["adaptive_sampled"]["per_seed"], online_phases["fixed_sampled"]["per_seed"]
                    )
            elif all(n in methods and all(math.isfinite(v) for v in per_seed(n, metric)) for n in names):
                result["comparisons"][f"{key}_sampled"] = compare(per_seed(names[0], metric), per_seed(names[1], metric))
        result["sampled"] = {
            paper_key: result["comparisons"].get(f"{key}_sampled", {}).get("change_pct", math.nan)
            for paper_key, key in CLAIM_COMPARISONS.items()
        }
    if "adaptive_style" in methods:
        result["style_context"] = {
            "with": "adaptive_style",
            "without": "adaptive",
            "reward_gain_pct": compare(per_seed("adaptive_style", "reward"), per_seed("adaptive", "reward")),
        }
    return result


def _online_phases(
    raw: Mapping[str, Mapping[int, Any]], methods: Mapping[str, Any], seeds: Sequence[int], phases: Sequence[int]
) -> dict[str, Any]:
    """The online phases behind (c): which were pooled, (c) within each, and the pooled per-run
    rewards of both arms (``runs``: phase-major, ``len(phases) · len(seeds)``): final evaluations
    (``adaptive``, ``fixed``, and ``*_sampled`` when every phase has them) and Phase-2 training
    episodes (``training_episodes``: empty unless every run has its log)."""

    def rewards(arm: str, suffix: str = "") -> list[float]:
        return [v for r in phases for v in methods[replicate_name(arm, r) + suffix]["reward"]["per_seed"]]

    out: dict[str, Any] = {"phases": list(phases), "runs": len(phases) * len(seeds), "per_phase": []}
    for r in phases:
        names = {arm: replicate_name(arm, r) for arm in ("adaptive", "fixed")}
        row: dict[str, Any] = {"phase": r, **{arm: methods[n]["reward"] for arm, n in names.items()}}
        row["change"] = compare(methods[names["adaptive"]]["reward"]["per_seed"], methods[names["fixed"]]["reward"]["per_seed"])
        if all(sampled_name(n) in methods for n in names.values()):
            row["change_sampled"] = compare(
                methods[sampled_name(names["adaptive"])]["reward"]["per_seed"],
                methods[sampled_name(names["fixed"])]["reward"]["per_seed"],
            )
        out["per_phase"].append(row)
    for arm in ("adaptive", "fixed"):
        for suffix in ("", "_sampled"):
            if suffix and not all(sampled_name(replicate_name(arm, r)) in methods for r in phases):
                continue
            values = rewards(arm, suffix)
            mean, half = t_confidence_interval(values) if values else (math.nan, math.nan)
            out[arm + suffix] = {"mean": mean, "ci95": half, "per_seed": values}  # per run
    logs = {
        arm: [raw.get(f"online/{replicate_name(arm, r)}", {}).get(s) for r in phases for s in seeds]
        for arm in ("adaptive", "fixed")
    }
    out["training_episodes"] = {}
    if phases and all(log is not None for runs in logs.values() for log in runs):
        for arm, runs in logs.items():
            stats = [online_phase_stats(log["episodes"]) for log in runs]
            out["training_episodes"][arm] = {key: [st[key] for st in stats] for key in ("reward", "reward_last")}
    return out


def _fmt(stat: Mapping[str, Any], digits: int = 2) -> str:
    mean, half = stat["mean"], stat["ci95"]
    if not math.isfinite(mean):
        return "n/a"
    return f"{mean:.{digits}f}" + ("" if not math.isfinite(half) else f" ± {half:.{digits}f}")


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{x:+.2f}%"


def paper_verdict(paper_key: str, change_pct: float) -> str:
    """``"at or beyond"`` when our relative change is at least as good as the paper's (higher reward,
    lower jerk), ``"short"`` otherwise (also for a NaN change)."""
    better_is_lower = paper_key == "offline_jerk_change_pct"
    ours, paper = float(change_pct), PAPER[paper_key]
    ok = ours <= paper if better_is_lower else ours >= paper
    return "at or beyond" if ok else "short"


def format_markdown(summary: Mapping[str, Any], command: str, date: str) -> str:
    """``fig2.md``: headline comparison with the paper, per-method table, style, sweeps."""
    c = summary["comparisons"]
    n = len(summary["seeds"])
    phases = summary.get("online_phases", {}).get("phases", [0])
    pooled = f" ({n} seeds × {len(phases)} online phases, pooled)" if len(phases) > 1 else ""
    lines = [
        "# Figure 2 reproduction on MixedTraffic-v0",
        "",
        f"Command: `{command}`  ",
        f"Date: {date}  ",
        f"Seeds: {summary['seeds']} (means ± 95% Student-t intervals over {n} seed(s); "
        "a single seed has no interval)",
        "",
        "Relative change = 100 · (method − baseline) / |baseline|, applied to the means over seeds; "
        "the per-seed column is the mean ± 95% interval of the per-seed changes. Where a claim is short "
        "of the paper, the README (section \"Reproducing the paper's Figure 2\") says what was tried. "
        "Rows without a suffix act with fixed candidate noise (`predict(deterministic=True)`: the same "
        "history always gives the same plan); rows marked \"sampled\" evaluate the same checkpoints "
        "drawing fresh candidate noise at every replanning, as the rollouts of Phase 2 do (seeded per "
        "episode).",
        "",
        "| claim | ours | per-seed changes | paper | vs paper |",
        "|---|---|---|---|---|",
    ]
    rows = (
        ("(a) offline reward, chunk vs one-step", "offline_reward", "offline_reward_gain_pct"),
        ("(b) cumulative jerk, chunk vs one-step", "offline_jerk", "offline_jerk_change_pct"),
        (f"(c) online reward, adaptive vs fixed{pooled}", "online_reward", "online_reward_gain_pct"),
    )
    extra = (
        (
            "(a') offline reward, chunk with adaptive execution vs one-step",
            "offline_reward_chunk_adaptive",
            None,
        ),
        (
            "(b') cumulative jerk, chunk with adaptive execution vs one-step",
            "offline_jerk_chunk_adaptive",
            None,
        ),
        ("(b'') jerk per step (Σ\\|jerk\\| / episode length), chunk vs one-step", "offline_jerk_per_step", None),
        (
            f"(c') online reward during Phase 2 (mean return of the training episodes), adaptive vs fixed{pooled}",
            "online_phase_reward",
            None,
        ),
        (f"(c'') the same over the last quarter of the training episodes{pooled}", "online_phase_reward_last", None),
        (
            "(c''') the execution rule alone: the fixed arm's checkpoint executed adaptively vs with fixed chunks"
            + (" (first online phase)" if pooled else ""),
            "online_execution_rule",
            None,
        ),
    )
    sampled_rows = tuple(
        (f"{label} — sampled", f"{key}_sampled", paper_key)
        for label, key, paper_key in (*rows, extra[2], extra[5])
    )
    for label, key, paper_key in (*rows, *extra, *sampled_rows):
        if key not in c:
            continue
        cmp = c[key]
        per_seed = _fmt({"mean": cmp["per_seed_mean_pct"], "ci95": cmp["per_seed_ci95_pct"]}) + "%"
        paper = "not in the paper" if paper_key is None else f"{PAPER[paper_key]:+.2f}%"
        verdict = "" if paper_key is None else paper_verdict(paper_key, cmp["change_pct"])
        lines.append(f"| {label} | {_pct(cmp['change_pct'])} | {per_seed} | {paper} | {verdict} |")
    style = summary.get("style")
    if style:
        lines.append(
            f"| (d) style inference, macro accuracy | {_fmt(style['macro_accuracy'], 3)} | | confusion matrix only | |"
        )
    lines += [
        "",
        "## Methods",
        "",
        "| method | reward | cum. jerk | jerk per step | collision rate | merge success | mean speed [m/s] | mean L_t |",
        "|---|---|---|---|---|---|---|---|",
    ]
    order = ["onestep", "chunk", "chunk_adaptive", "fixed", "adaptive", "fixed_adaptive", "adaptive_style"]
    order += [sampled_name(m) for m in SAMPLED_METHODS]
    for m in order:
        if m not in summary["methods"]:
            continue
        s = summary["methods"][m]
        lines.append(
            f"| {METHOD_LABELS[m]} | {_fmt(s['reward'])} | {_fmt(s['cumulative_jerk'], 1)} "
            f"| {_fmt(s['jerk_per_step'])} | {_fmt(s['collision'])} "
            f"| {_fmt(s['merge_success'])} | {_fmt(s['mean_speed'])} | {_fmt(s['mean_executed_length'])} |"
        )
    if len(phases) > 1:
        offset = summary["budget"].get("online_seed_offset", 0)
        lines += [
            "",
            "## (c) per online phase (both arms fine-tuned again from the same pre-trained checkpoint)",
            "",
            "The methods table and the Phase-2 table show the first online phase; (c), (c') and (c'') pool "
            f"the {summary['online_phases']['runs']} paired runs of all phases. Phase r runs seed s with "
            f"s + {MAX_SEED} × (online_seed_offset + r).",
            "",
            "| online phase | fixed | adaptive | (c) | (c) sampled |",
            "|---|---|---|---|---|",
        ]
        for row in summary["online_phases"]["per_phase"]:
            sampled_change = _pct(row["change_sampled"]["change_pct"]) if "change_sampled" in row else ""
            lines.append(
                f"| {offset + row['phase']} | {_fmt(row['fixed'])} | {_fmt(row['adaptive'])} "
                f"| {_pct(row['change']['change_pct'])} | {sampled_change} |"
            )
        op = summary["online_phases"]
        sampled_pooled = _pct(c["online_reward_sampled"]["change_pct"]) if "online_reward_sampled" in c else ""
        lines.append(
            f"| pooled ({op['runs']} runs) | {_fmt(op['fixed'])} | {_fmt(op['adaptive'])} "
            f"| {_pct(c['online_reward']['change_pct'])} | {sampled_pooled} |"
        )
    if summary.get("online_phase"):
        lines += [
            "",
            "## Phase 2: the training episodes (candidates drawn with fresh noise, as during training)"
            + (", first online phase" if len(phases) > 1 else ""),
            "",
            "| arm | mean return | mean return, last quarter | collision rate | episodes |",
            "|---|---|---|---|---|",
        ]
        for arm, st in summary["online_phase"].items():
            lines.append(
                f"| {METHOD_LABELS[arm]} | {_fmt(st['reward'])} | {_fmt(st['reward_last'])} "
                f"| {_fmt(st['collision'])} | {_fmt(st['episodes'], 1)} |"
            )
    if style:
        lines += [
            "",
            "## (d) Driving-style inference",
            "",
            f"Confusion matrix ({style['confusion_matrix_layout']}):",
            "",
            "| inferred \\ truth | " + " | ".join(style["classes"]) + " |",
            "|---" * (len(style["classes"]) + 1) + "|",
        ]
        for name, row in zip(style["classes"], style["confusion_matrix"], strict=True):
            lines.append(f"| {name} | " + " | ".join(str(v) for v in row) + " |")
        if style["baseline_macro_accuracy_per_seed"]:
            base = t_confidence_interval(style["baseline_macro_accuracy_per_seed"])
            lines += [
                "",
                f"Logistic-regression baseline on summary features: macro accuracy "
                f"{_fmt({'mean': base[0], 'ci95': base[1]}, 3)}.",
            ]
    if summary["delta_sweep"]:
        lines += [
            "",
            "## δ sweep (fine-tuned adaptive checkpoint, execution threshold only)",
            "",
            "| δ | mean L_t | reward | cum. jerk |",
            "|---|---|---|---|",
        ]
        for row in summary["delta_sweep"]:
            lines.append(
                f"| {row['delta']:g} | {_fmt(row['mean_executed_length'])} | {_fmt(row['reward'])} "
                f"| {_fmt(row['cumulative_jerk'], 1)} |"
            )
    if summary["k_sweep"]:
        lines += [
            "",
            "## k sweep (offline, same data and gradient budget, full chunks)",
            "",
            "| k | reward | cum. jerk | collision rate |",
            "|---|---|---|---|",
        ]
        for row in summary["k_sweep"]:
            lines.append(
                f"| {row['k']} | {_fmt(row['reward'])} | {_fmt(row['cumulative_jerk'], 1)} "
                f"| {_fmt(row['collision'])} |"
            )
    if summary.get("acting_sweep"):
        default = summary.get("acting_default", {"n_elite": 1})
        lines += [
            "",
            "## Acting rule (offline checkpoints, full chunks): N Euler steps of the sampler, elite mean of "
            f"the m best candidates (`flow_steps`, `n_elite`); (a) and (b) act with the checkpoints' N and "
            f"m = {default['n_elite']}",
            "",
            "| N | m | one-step reward | chunk reward | one-step cum. jerk | chunk cum. jerk | jerk change | "
            "chunk jerk per step | chunk collision rate |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for row in summary["acting_sweep"]:
            one, ch = row["onestep"], row["chunk"]
            lines.append(
                f"| {row['flow_steps']} | {row['n_elite']} | {_fmt(one['reward'])} | {_fmt(ch['reward'])} "
                f"| {_fmt(one['cumulative_jerk'], 1)} "
                f"| {_fmt(ch['cumulative_jerk'], 1)} | {_pct(row['jerk_change']['change_pct'])} "
                f"| {_fmt(ch['jerk_per_step'])} | {_fmt(ch['collision'])} |"
            )
    if "style_context" in summary:
        cmp = summary["style_context"]["reward_gain_pct"]
        lines += [
            "",
            "## Style context c_t (Eq. 6) in the observation",
            "",
            f"Adaptive arm with vs without c_t (own dataset, same budgets): reward change "
            f"{_pct(cmp['change_pct'])} (per seed {_fmt({'mean': cmp['per_seed_mean_pct'], 'ci95': cmp['per_seed_ci95_pct']})}%).",
        ]
    b = summary["budget"]
    lines += [
        "",
        "## Budget (per seed)",
        "",
        f"{b['dataset_episodes']} offline episodes; {b['pretrain_steps']} gradient steps per pre-trained arm; "
        f"{b['finetune_steps']} online steps per fine-tuned arm"
        + (f" in each of {b['online_replicates']} online phases" if b.get("online_replicates", 1) > 1 else "")
        + f"; {b['eval_episodes']} evaluation episode(s) per "
        f"method and seed; k = {b['chunk_size']}, δ = {b['entropy_threshold']:g}; env {b['env_kwargs'] or 'defaults'}; "
        f"UA2C {b['algo_kwargs'] or 'defaults'}"
        + (f"; one-step baseline {b['onestep_kwargs']}" if b.get("onestep_kwargs") else "")
        + (f"; Phase 2 {b['finetune_kwargs']}" if b.get("finetune_kwargs") else "")
        + (
            f"; Phase 2 seeds offset by {MAX_SEED} × {b['online_seed_offset']}"
            if b.get("online_seed_offset")
            else ""
        )
        + ".",
    ]
    seconds = summary.get("seconds", {})
    if seconds.get("measured"):
        measured, estimated = seconds["measured"], seconds.get("estimated", {})
        lines += [
            "",
            "Compute, summed over seeds (one worker = one core; measured = units run by the calls "
            "that built these results):",
            "",
            "| stage | measured [min] | estimated [min] |",
            "|---|---|---|",
        ]
        for stage in (*[k for k in estimated if k != "total"], "total"):
            got = measured.get(stage)
            lines.append(
                f"| {stage} | {'n/a' if got is None else f'{got / 60:.1f}'} | {estimated.get(stage, math.nan) / 60:.1f} |"
            )
    lines.append("")
    return "\n".join(lines)


def _bar_panel(
    path: Path, title: str, ylabel: str, arms: Sequence[tuple[str, Mapping[str, Any]]], note: str
) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.2, 3.6), dpi=120)  # no pyplot: the caller's backend stays untouched
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for i, (_label, stat) in enumerate(arms):
        half = stat["ci95"] if math.isfinite(stat["ci95"]) else 0.0
        ax.bar(i, stat["mean"], yerr=half, capsize=6, color=("#9e9e9e", "#1f77b4")[i % 2], alpha=0.85)
        ax.scatter(
            np.full(len(stat["per_seed"]), i) + np.linspace(-0.15, 0.15, len(stat["per_seed"])),
            stat["per_seed"],
            color="black",
            s=12,
            zorder=3,
        )
    ax.set_xticks(range(len(arms)), [a[0] for a in arms])
    ax.set_ylabel(ylabel)
    ax.set_title(f"{title}\n{note}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)


def _sweep_panel(path: Path, summary: Mapping[str, Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.4, 3.6), dpi=120)
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for row in summary["delta_sweep"]:
        x, y = row["mean_executed_length"], row["reward"]
        ax1.errorbar(
            x["mean"], y["mean"], xerr=np.nan_to_num(x["ci95"]), yerr=np.nan_to_num(y["ci95"]), fmt="o"
        )
        ax1.annotate(
            f"δ={row['delta']:g}",
            (x["mean"], y["mean"]),
            fontsize=7,
            xytext=(3, 3),
            textcoords="offset points",
        )
    ax1.set_xlabel("mean executed length L_t")
    ax1.set_ylabel("episode reward")
    ax1.set_title("δ sweep (adaptive checkpoint)", fontsize=9)
    ks = summary["k_sweep"]
    if ks:
        ax2.errorbar(
            [r["k"] for r in ks],
            [r["reward"]["mean"] for r in ks],
            yerr=[np.nan_to_num(r["reward"]["ci95"]) for r in ks],
            fmt="o-",
        )
    ax2.set_xlabel("chunk length k")
    ax2.set_ylabel("offline episode reward")
    ax2.set_title("k sweep (same gradient budget)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)


def _curve_panel(path: Path, summary: Mapping[str, Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.2, 3.6), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for arm, st in summary["online_phase"].items():
        curve = st["curve"]
        ax.plot(curve["steps"], curve["reward"], "o-", label=METHOD_LABELS[arm], markersize=3)
    ax.set_xlabel("online environment steps")
    ax.set_ylabel("training episode return")
    ax.set_title(f"(c) Phase 2 training episodes, mean over {len(summary['seeds'])} seed(s)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def strict_json(obj: Any) -> Any:
    """A copy of ``obj`` that strict JSON parsers accept: NaN -> ``None``, ±inf -> ``"inf"``/``"-inf"``."""
    if isinstance(obj, Mapping):
        return {str(k): strict_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict_json(v) for v in obj]
    if isinstance(obj, float | np.floating):
        value = float(obj)
        if math.isnan(value):
            return None
        return value if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_report(summary: Mapping[str, Any], paths: RunPaths, command: str, date: str) -> list[Path]:
    """Write ``fig2.json``, ``fig2.md`` and the PNG panels into ``paths.out``; return the files."""
    from sb3_ua2c.pipeline import write_json

    out = paths.out
    out.mkdir(parents=True, exist_ok=True)
    m, c = summary["methods"], summary["comparisons"]
    files = [write_json(out / "fig2.json", strict_json({**summary, "command": command, "date": date}))]
    md = out / "fig2.md"
    md.write_text(format_markdown(summary, command, date))
    files.append(md)
    panels = (
        (
            "fig2_a_offline_reward.png",
            "(a) offline reward",
            "episode reward",
            ("onestep", "chunk"),
            "reward",
            c["offline_reward"]["change_pct"],
            PAPER["offline_reward_gain_pct"],
        ),
        (
            "fig2_b_offline_jerk.png",
            "(b) offline cumulative jerk",
            "Σ|jerk| [m/s³]",
            ("onestep", "chunk"),
            "cumulative_jerk",
            c["offline_jerk"]["change_pct"],
            PAPER["offline_jerk_change_pct"],
        ),
        (
            "fig2_c_online_reward.png",
            "(c) online reward",
            "episode reward",
            ("fixed", "adaptive"),
            "reward",
            c["online_reward"]["change_pct"],
            PAPER["online_reward_gain_pct"],
        ),
    )
    if "sampled" in summary:  # the same panels for the evaluations with fresh candidate noise
        panels += tuple(
            (name.replace(".png", "_sampled.png"), f"{title}, sampled", ylabel, arms, key, summary["sampled"][pk], paper)
            for (name, title, ylabel, arms, key, _, paper), pk in zip(panels, CLAIM_COMPARISONS, strict=True)
        )
    short = {"onestep": "one-step", "chunk": "chunk", "fixed": "fixed", "adaptive": "adaptive"}
    op = summary.get("online_phases", {})
    for name, title, ylabel, arms, key, ours, paper in panels:
        suffix = "_sampled" if name.endswith("_sampled.png") else ""
        stats = {a: m[a + suffix][key] for a in arms}
        if name.startswith("fig2_c_online_reward") and len(op.get("phases", [0])) > 1:  # every pooled run
            stats, title = {a: op[a + suffix] for a in arms}, f"{title}, {op['runs']} runs"
        _bar_panel(out / name, title, ylabel, [(short[a], stats[a]) for a in arms], f"ours {_pct(ours)}, paper {paper:+.2f}%")
        files.append(out / name)
    if "style" in summary:
        from sb3_ua2c.style import plot_confusion

        st = summary["style"]
        plot_confusion(
            np.asarray(st["confusion_matrix"]),
            out / "fig2_d_style_confusion.png",
            st["classes"],
            title=f"(d) driving style, macro acc {_fmt(st['macro_accuracy'], 3)}",
        )
        files.append(out / "fig2_d_style_confusion.png")
    if summary.get("online_phase"):
        _curve_panel(out / "fig2_c_online_curves.png", summary)
        files.append(out / "fig2_c_online_curves.png")
    if summary["delta_sweep"] or summary["k_sweep"]:
        _sweep_panel(out / "fig2_sweeps.png", summary)
        files.append(out / "fig2_sweeps.png")
    return files


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------


def recorded_budget(report: str | os.PathLike) -> Fig2Budget:
    """The budget a report ran with: the ``budget`` key of its ``fig2.json`` (``report`` is that file or
    the directory holding it). Fields newer than the report take their class defaults, which are the
    values every report made before them ran with.

    :raises ValueError: naming the path, when it holds no readable ``fig2.json`` with a budget
    """
    path = Path(report)
    path = path / "fig2.json" if path.is_dir() else path
    try:
        recorded = json.loads(path.read_text())["budget"]
    except FileNotFoundError:
        raise ValueError(f"--budget-of: {path} does not exist") from None
    except (json.JSONDecodeError, TypeError, KeyError) as exc:
        raise ValueError(f"--budget-of: {path} is not a fig2.json with a 'budget' key ({exc!r})") from exc
    return Fig2Budget.from_dict(recorded)


def build_parser(prog: str = "python benchmarks/fig2.py") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Reproduce the UA2C paper's Figure 2 (a)-(d) on MixedTraffic-v0 over several seeds, with the "
        "δ, k and style-context sweeps. Resumable: finished units (datasets, checkpoints, evaluations) are skipped.",
    )
    parser.add_argument("--seeds", type=int, default=5, help="number of seeds 0..N-1 (default: 5)")
    parser.add_argument(
        "--seed-list", type=int, nargs="+", default=None, help="explicit seeds (overrides --seeds)"
    )
    parser.add_argument(
        "--quick", action="store_true", help="tiny budget (4-s episodes, a few updates): a smoke test"
    )
    parser.add_argument(
        "--budget",
        type=json_object_arg,
        default={},
        help="Fig2Budget overrides as JSON, e.g. '{\"pretrain_steps\": 4000}'",
    )
    parser.add_argument(
        "--budget-of",
        default=None,
        metavar="REPORT",
        help="start from the budget a report ran with (its fig2.json, or the directory holding it) instead of "
        "the default; --budget applies on top. Reruns a report made under another default exactly",
    )
    parser.add_argument("--out", default="results", help="report directory (default: results)")
    parser.add_argument("--raw", default=None, help="per-seed raw JSON directory (default: <out>/fig2_raw)")
    parser.add_argument("--work", default=None, help="datasets and checkpoints (default: <out>/fig2_work)")
    parser.add_argument("--workers", type=int, default=2, help="seeds run in parallel processes (default: 2)")
    parser.add_argument(
        "--report-only", action="store_true", help="only rebuild the report from the raw results"
    )
    return parser


def main(argv: Sequence[str] | None = None, prog: str = "python benchmarks/fig2.py") -> int:
    """Entry point; returns the exit code (2 on a bad argument or missing results).

    :param argv: arguments (default ``sys.argv[1:]``)
    :param prog: how the command was invoked, for the help text and the report's command line
    """
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    try:
        if args.budget_of is not None and args.quick:
            raise ValueError("--budget-of and --quick both choose the base budget: pass one of them")
        base = recorded_budget(args.budget_of) if args.budget_of is not None else QUICK_BUDGET if args.quick else FULL_BUDGET
        budget = base.replace(**args.budget) if args.budget else base
        if args.seed_list is not None:
            seeds = list(dict.fromkeys(args.seed_list))
        else:
            check_int("Fig2Budget.seeds", args.seeds)
            seeds = list(range(args.seeds))
        if any(not 0 <= s < MAX_SEED for s in seeds):
            raise ValueError(f"seeds must be in [0, {MAX_SEED}), got {seeds}")
        check_int("Fig2Budget.workers", args.workers)
    except ValueError as exc:
        parser.error(str(exc))
    paths = RunPaths.under(args.out, args.raw, args.work)
    command = command_line(prog, sys.argv[1:] if argv is None else argv)
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    t0 = time.perf_counter()
    try:
        if not args.report_only:
            est = estimate_seconds(budget, len(seeds))
            workers = min(args.workers, len(seeds))
            wall = est["total"] / len(seeds) * math.ceil(len(seeds) / workers)  # seeds run whole on a worker
            print(
                f"Figure 2: seeds {seeds}, {workers} worker(s); estimated {est['total'] / 60:.1f} CPU-min, "
                f"~{wall / 60:.0f} min wall before resuming ("
                + ", ".join(f"{k} {v / 60:.1f}" for k, v in est.items() if k != "total")
                + " CPU-min)",
                flush=True,
            )
            executed = run_all(seeds, budget, paths, workers)
            print(f"{len(executed)} unit(s) run in {time.perf_counter() - t0:.0f} s", flush=True)
        recorded: dict[str, Any] = {}
        if args.report_only:
            previous = paths.out / "fig2.json"
            if previous.is_file():  # a rebuilt report keeps the command and date of the run
                recorded = json.loads(previous.read_text())
                command, date = recorded.get("command", command), recorded.get("date", date)
            # the budget the run was made with: its manifest, else the one recorded in fig2.json
            manifest = read_manifest(paths)
            if manifest is None and "budget" in recorded:
                manifest = Fig2Budget.from_dict(recorded["budget"])
            budget = manifest or budget
        summary = aggregate(load_raw(paths, seeds), seeds, budget)
        summary["seconds"] = {
            # without the work directory (e.g. a fresh clone), the timings recorded with the run
            "measured": measured_seconds(paths, seeds) or recorded.get("seconds", {}).get("measured", {}),
            "estimated": estimate_seconds(budget, len(seeds)),
        }
    except (ValueError, FileNotFoundError, SeedBusyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    files = write_report(summary, paths, command, date)
    for label, key in (
        ("offline reward", "offline_reward_gain_pct"),
        ("offline jerk", "offline_jerk_change_pct"),
        ("online reward", "online_reward_gain_pct"),
    ):
        print(f"{label}: ours {_pct(summary[key])}, paper {PAPER[key]:+.2f}%")
    print(f"style macro accuracy: {summary['style_macro_accuracy']:.3f}")
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


__all__ = [
    "FULL_BUDGET",
    "PAPER",
    "QUICK_BUDGET",
    "CostModel",
    "Fig2Budget",
    "RunPaths",
    "SeedBusyError",
    "aggregate",
    "check_manifest",
    "compare",
    "estimate_seconds",
    "format_markdown",
    "load_raw",
    "main",
    "measured_seconds",
    "read_manifest",
    "relative_change_pct",
    "run_all",
    "run_seed",
    "seed_lock",
    "strict_json",
    "student_t_quantile",
    "student_t_two_sided_cdf",
    "t_confidence_interval",
    "write_manifest",
    "write_report",
]
