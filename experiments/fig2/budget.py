"""Configuration of a Figure-2 run: :class:`Fig2Budget` (default and ``--quick`` budgets) and the
:class:`CostModel` behind its wall-time estimate.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from experiments.common.names import MAIN_METHODS, SAMPLED_METHODS
from experiments.common.runner import list_schedule_seconds
from sb3_ua2c.checks import check_int


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


#: The velocity field :class:`CostModel` was measured with (the paper's 128 × 2)
COST_REFERENCE_NET_ARCH = (128, 128)


def velocity_field_weights(kwargs: Mapping[str, Any]) -> int:
    """Hidden-to-hidden weights of the velocity field that UA2C arguments ``kwargs`` build
    (``policy_kwargs["net_arch"]``, else UA2C's default), the part of its size that grows with the
    hidden widths (128 × 2: 16,384)."""
    from sb3_ua2c.policies import DEFAULT_NET_ARCH

    net_arch = list(_policy_kwargs(kwargs).get("net_arch") or DEFAULT_NET_ARCH)
    return sum(a * b for a, b in zip(net_arch[:-1], net_arch[1:], strict=False))


def extra_kweights(kwargs: Mapping[str, Any]) -> float:
    """Hidden weights of the velocity field built by UA2C arguments ``kwargs`` beyond the
    :data:`COST_REFERENCE_NET_ARCH` the cost model was measured with, in thousands (0 for smaller
    fields): what :class:`CostModel` scales with."""
    reference = velocity_field_weights({"policy_kwargs": {"net_arch": list(COST_REFERENCE_NET_ARCH)}})
    return max(0, velocity_field_weights(kwargs) - reference) / 1000


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


STYLE_STAGES = ("style", "style_ablation")
"""The stages of :func:`estimate_seconds` that a seed's ``"style"`` part runs; the ``"main"`` part runs the rest."""


def estimate_wall_seconds(stages: Mapping[str, float], n_seeds: int, workers: int) -> float:
    """Wall time of a run whose CPU seconds per stage are ``stages`` (:func:`estimate_seconds`): each
    seed's two parts (``"main"``, then ``"style"``: :data:`STYLE_STAGES`) scheduled as
    :func:`experiments.fig2.units.run_all` submits them, every main part before the style parts.

    :param stages: CPU seconds per stage over all seeds, with ``"total"``
    :param n_seeds: number of seeds (>= 1)
    :param workers: workers at once (>= 1)
    """
    check_int("n_seeds", n_seeds)
    style = sum(stages.get(name, 0.0) for name in STYLE_STAGES) / n_seeds
    main = stages["total"] / n_seeds - style
    return list_schedule_seconds([main] * n_seeds + [style] * n_seeds, workers)  # run_all's order


def finetune_overrides(budget: Fig2Budget) -> dict[str, Any]:
    """Phase-2 update cadence of every fine-tuned arm: one gradient step per ``chunk_size`` env steps.

    UA2C's default (one update per plan) would give the adaptive arm, whose plans are shorter,
    up to ``k`` times the updates of the fixed arm for the same environment steps. The budget's
    ``finetune_kwargs`` come on top.
    """
    return {**budget.finetune_kwargs, "train_freq": budget.chunk_size, "gradient_steps": 1}
