"""Budget, arms and cost model of the head-to-head (``python -m experiments.peers``).

Every arm of a seed runs on the Figure-2 protocol of that seed: the same dataset (Figure 2's, built
once per seed), the same online env-step budget, the same held-out evaluation scenarios. The UA2C
arms are Figure 2's: pre-trained offline (one-step k = 1, chunk k), then fine-tuned online from that
checkpoint, acting with adaptive chunks (δ of the budget), fixed chunks (δ = inf) or one step.

The estimate (:func:`estimate_units`) prices every unit in CPU seconds on one core: the UA2C units
with Figure 2's :class:`~experiments.fig2.budget.CostModel`, the peer units with
:class:`PeerCostModel`, calibrated on ``experiments/peers/measure_costs.py`` (CPU seconds of one unit at 10,000
online and 6,000 offline steps, 20 evaluation episodes: SAC 180, TQC 319, SAC + offline 180, IQL
389, Cal-QL 2,190; measured side by side with SAC or IQL on 2026-12-04 and scaled to them: CrossQ's
update at 1.22x SAC's, ReBRAC's offline and online steps at 1.21x and 1.14x IQL's, BC's offline step
at 0.27x IQL's, RLPD's env step with one update at 1.19x IQL's). The wall time is the sum over the stages (datasets, pre-training, arms) of the
longest-first schedule of their units on the workers (:func:`~experiments.common.runner.list_schedule_seconds`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from experiments.common.names import SCENARIO_BASES
from experiments.common.runner import list_schedule_seconds
from experiments.fig2.budget import (
    FULL_BUDGET,
    QUICK_BUDGET,
    CostModel,
    Fig2Budget,
    extra_kweights,
    finetune_overrides,
)
from sb3_ua2c.checks import check_int


@dataclass(frozen=True)
class UA2CArm:
    """How a UA2C arm is built from the budget.

    :param k: chunk length (``"k"``: the budget's ``chunk_size``)
    :param delta: δ it acts with (``"delta"``: the budget's ``entropy_threshold``; ``"inf"``: fixed
        chunks; ``None``: its checkpoint's own, so one step for ``k = 1`` and Eq. 7's δ for the preset)
    :param config: its constructor arguments: ``"budget"``, the budget's ``algo_kwargs`` over UA2C's
        defaults; ``"paper"``, the preset :data:`sb3_ua2c.presets.PAPER` with the budget's optimisation
        settings (``learning_rate``, ``batch_size``, ``gamma``, ``tau``)
    :param cadence: its online updates: ``"fig2"``, one gradient step per ``chunk_size`` env steps
        (Figure 2's); ``"per_step"``, one per env step (the peers'); ``"own"``, its configuration's
        ``train_freq`` and ``gradient_steps``
    """

    k: str | int = "k"
    delta: str | None = "delta"
    config: str = "budget"
    cadence: str = "fig2"


#: UA2C arms by name. ``ua2c`` is UA2C as a user gets it (the defaults of this release with the
#: budget's ``algo_kwargs``, its own update schedule), ``ua2c_paper`` the paper as written (the
#: preset); ``ua2c_fixed`` and ``ua2c_onestep`` are ``ua2c`` with δ = inf and with k = 1 at the same
#: schedule, the arms Figure 2 (a)-(c) compare with it; ``ua2c_adaptive`` is ``ua2c`` at Figure 2's
#: cadence (the paper's one update per ``k`` env steps), ``ua2c_adaptive_per_step`` at the peers'.
UA2C_ARMS: dict[str, UA2CArm] = {
    "ua2c": UA2CArm(cadence="own"),
    "ua2c_paper": UA2CArm(delta=None, config="paper", cadence="own"),
    "ua2c_adaptive": UA2CArm(),
    "ua2c_fixed": UA2CArm(delta="inf", cadence="own"),
    "ua2c_onestep": UA2CArm(k=1, delta=None, cadence="own"),
    "ua2c_adaptive_per_step": UA2CArm(cadence="per_step"),
}
_CADENCE_TEXT = {"fig2": "one gradient step per chunk_size env steps (Figure 2's cadence)",
                 "per_step": "one gradient step per env step (the peers' cadence)",
                 "own": "its configuration's own train_freq and gradient_steps"}


def describe_ua2c_arm(arm: str) -> str:
    """A UA2C arm in words, for its record's ``notes``: its configuration and its online update cadence."""
    spec = UA2C_ARMS[arm]
    config = "preset('paper')" if spec.config == "paper" else "the defaults with the budget's algo_kwargs"
    return (f"UA2C ({arm}: {config}): offline checkpoint, then online with the offline data in its buffer and "
            f"{_CADENCE_TEXT[spec.cadence]}")


#: UA2C constructor arguments of a budget that the preset leaves to the problem (``"paper"`` arms keep them)
OPTIMISATION_KEYS = ("learning_rate", "batch_size", "gamma", "tau")
#: Peer arms: SB3 online from scratch, SAC with the offline data in half of each batch, d3rlpy offline then online.
PEER_ARMS = ("sac", "tqc", "crossq", "sac_offline_mix", "rlpd", "iql", "calql", "rebrac")
#: Reference rows, nothing learned online: the dataset's behaviour policy and behaviour cloning of the dataset
REFERENCE_ARMS = ("behaviour", "bc")
#: Peer arms trained online from scratch by Stable-Baselines3 / sb3-contrib (``zoo_configs/<arm>.yml``).
ONLINE_SB3_ARMS = ("sac", "tqc", "crossq")
ARMS = (*UA2C_ARMS, *PEER_ARMS, *REFERENCE_ARMS)
D3RLPY_ARMS = ("rlpd", "iql", "calql", "rebrac", "bc")
#: d3rlpy arms without an online phase
OFFLINE_ONLY_ARMS = ("bc",)
ARM_LABELS = {
    "ua2c": "UA2C (defaults)",
    "ua2c_paper": "UA2C as in the paper (preset)",
    "ua2c_adaptive": "UA2C adaptive, one update per k env steps",
    "ua2c_fixed": "UA2C (defaults) fixed chunks (δ=inf)",
    "ua2c_onestep": "UA2C (defaults) one-step (k=1)",
    "ua2c_adaptive_per_step": "UA2C adaptive, one update per env step",
    "sac": "SB3 SAC (online)",
    "tqc": "sb3-contrib TQC (online)",
    "crossq": "sb3-contrib CrossQ (online)",
    "sac_offline_mix": "SAC + offline data (symmetric sampling)",
    "rlpd": "RLPD (d3rlpy SAC, layer-norm critics)",
    "iql": "d3rlpy IQL (offline → online)",
    "calql": "d3rlpy Cal-QL (offline → online)",
    "rebrac": "d3rlpy ReBRAC (offline → online)",
    "behaviour": "behaviour policy of the data (reference)",
    "bc": "d3rlpy BC (offline only, reference)",
    "iql_best_of_n": "d3rlpy IQL acting by the best of N actions under its critic",
}


@dataclass(frozen=True)
class PeersBudget:
    """Budget of a head-to-head run (per seed); a bad value raises ``ValueError`` naming it.

    :param ua2c: the Figure-2 budget the UA2C arms and the shared inputs come from: dataset
        (``dataset_episodes``, ``env_kwargs``), offline gradient steps (``pretrain_steps``, also the
        d3rlpy arms' offline steps), online env steps of EVERY arm (``finetune_steps``), evaluation
        episodes, ``chunk_size``, δ and the UA2C constructor arguments
    :param sb3_hyperparams: constructor arguments replacing those of ``zoo_configs/{sac,tqc}.yml`` key by
        key, for the SAC, TQC and SAC + offline arms (empty: the zoo's)
    :param d3rlpy_batch_size: minibatch size of IQL and Cal-QL (the SAC zoo entry's 256)
    :param calql_offline_steps: offline gradient steps of Cal-QL (``None``: ``ua2c.pretrain_steps``,
        like every other offline phase)
    :param rlpd_updates_per_step: gradient steps per online env step of the RLPD arm (its update-to-data
        ratio; RLPD's paper: 20, here as many as the budget allows)
    :param scenarios: the evaluation scenarios of every arm (:data:`~experiments.common.names.SCENARIO_BASES`):
        ``"validation"`` for choices (tuning), ``"test"`` for reported numbers, ``"figure2"`` for Figure 2's
        held-out scenarios (those of the records made before the split; UA2C's earlier choices were made on them)
    :param iql_best_of_n: IQL's final policy is also evaluated acting as UA2C does, by the best of this
        many sampled actions under its critic (the report's row ``iql_best_of_n``; 0: not)
    :param peer_kwargs: per peer arm, hyperparameters on top of its defaults (a tuning configuration): SB3
        constructor arguments for the SB3 arms (after ``sb3_hyperparams``), d3rlpy config arguments for the
        d3rlpy arms (after their published settings), e.g. ``{"iql": {"expectile": 0.9, "weight_temp": 10.0}}``
    """

    ua2c: Fig2Budget = field(default_factory=lambda: FULL_BUDGET.replace(finetune_steps=5000))
    sb3_hyperparams: Mapping[str, Any] = field(default_factory=dict)
    d3rlpy_batch_size: int = 256
    calql_offline_steps: int | None = None
    rlpd_updates_per_step: int = 4
    scenarios: str = "test"
    iql_best_of_n: int = 32
    peer_kwargs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.ua2c, Fig2Budget):
            raise TypeError(f"PeersBudget.ua2c must be a Fig2Budget, got {type(self.ua2c).__name__}")
        if not isinstance(self.sb3_hyperparams, Mapping):
            raise ValueError(f"PeersBudget.sb3_hyperparams must be a mapping, got {self.sb3_hyperparams!r}")
        check_int("PeersBudget.d3rlpy_batch_size", self.d3rlpy_batch_size)
        if self.calql_offline_steps is not None:
            check_int("PeersBudget.calql_offline_steps", self.calql_offline_steps)
        check_int("PeersBudget.rlpd_updates_per_step", self.rlpd_updates_per_step)
        check_int("PeersBudget.iql_best_of_n", self.iql_best_of_n, low=0)
        if self.scenarios not in SCENARIO_BASES:
            raise ValueError(f"PeersBudget.scenarios must be one of {list(SCENARIO_BASES)}, got {self.scenarios!r}")
        object.__setattr__(self, "sb3_hyperparams", dict(self.sb3_hyperparams))
        if not isinstance(self.peer_kwargs, Mapping):
            raise ValueError(f"PeersBudget.peer_kwargs must be a mapping of arm to mapping, got {self.peer_kwargs!r}")
        for arm, kwargs in self.peer_kwargs.items():
            if arm not in (*PEER_ARMS, "bc"):
                raise ValueError(f"PeersBudget.peer_kwargs: {arm!r} is not a peer arm; choose from {[*PEER_ARMS, 'bc']}")
            if not isinstance(kwargs, Mapping):
                raise ValueError(f"PeersBudget.peer_kwargs[{arm!r}] must be a mapping, got {kwargs!r}")
        object.__setattr__(self, "peer_kwargs", {a: dict(k) for a, k in self.peer_kwargs.items()})

    @property
    def online_steps(self) -> int:
        """Online environment steps of every arm."""
        return self.ua2c.finetune_steps

    def offline_steps(self, arm: str) -> int:
        """Offline gradient steps of ``arm`` (0 for the arms without an offline phase)."""
        if arm == "calql" and self.calql_offline_steps is not None:
            return self.calql_offline_steps
        if arm == "rlpd":  # RLPD learns online from the start, with the offline data in half of each batch
            return 0
        return self.ua2c.pretrain_steps if arm in UA2C_ARMS or arm in D3RLPY_ARMS else 0

    def sb3_kwargs(self, arm: str) -> dict[str, Any]:
        """Constructor arguments of an SB3 arm replacing its zoo file's: ``sb3_hyperparams``, then its ``peer_kwargs``."""
        return {**self.sb3_hyperparams, **self.peer_kwargs.get(arm, {})}

    def updates_per_step(self, arm: str) -> int:
        """Gradient steps per online env step of a peer arm (the UA2C arms: see ``Fig2Budget``)."""
        return self.rlpd_updates_per_step if arm == "rlpd" else 1

    def chunk_length(self, arm: str) -> int:
        """Chunk length of a UA2C arm."""
        k = UA2C_ARMS[arm].k
        return self.ua2c.chunk_size if k == "k" else int(k)

    def delta(self, arm: str) -> float | None:
        """δ a UA2C arm acts with (``inf``: fixed chunks; ``None``: its checkpoint's)."""
        d = UA2C_ARMS[arm].delta
        return None if d is None else float("inf") if d == "inf" else self.ua2c.entropy_threshold

    def pretrain_name(self, arm: str) -> str:
        """Name of the pre-trained checkpoint a UA2C arm starts from (shared by the arms of one configuration
        and chunk length): ``pretrain_k<k>``, ``pretrain_k<k>_paper`` for the preset."""
        suffix = "_paper" if UA2C_ARMS[arm].config == "paper" else ""
        return f"pretrain_k{self.chunk_length(arm)}{suffix}"

    def pretrain_kwargs(self, arm: str) -> dict[str, Any]:
        """UA2C constructor arguments a UA2C arm is pre-trained with."""
        k = self.chunk_length(arm)
        if UA2C_ARMS[arm].config == "paper":
            from sb3_ua2c.presets import preset

            kept = {key: v for key, v in self.ua2c.algo_kwargs.items() if key in OPTIMISATION_KEYS}
            return {**kept, **preset("paper"), "chunk_size": k}
        return self.ua2c.arm_kwargs(k)

    def finetune_overrides(self, arm: str) -> dict[str, Any]:
        """Phase-2 attributes of a UA2C arm: its update cadence (:class:`UA2CArm`) and, for the budget's
        configuration, the budget's ``finetune_kwargs``."""
        spec = UA2C_ARMS[arm]
        if spec.cadence == "own":
            return {} if spec.config == "paper" else dict(self.ua2c.finetune_kwargs)
        overrides = finetune_overrides(self.ua2c)
        if spec.cadence == "per_step":
            overrides = {**overrides, "train_freq": 1, "gradient_steps": 1}
        return overrides

    def steps_per_update(self, arm: str, plan_length: float) -> float:
        """Online env steps per gradient step of a UA2C arm (``plan_length``: its mean plan length, what
        ``gradient_steps=-1`` counts)."""
        kwargs = {**_ua2c_schedule_defaults(), **self.pretrain_kwargs(arm), **self.finetune_overrides(arm)}
        if kwargs["gradient_steps"] == -1:
            return plan_length
        freq = kwargs["train_freq"]
        steps = freq if isinstance(freq, int) else freq[0] if freq[1] == "step" else steps_per_episode(self.ua2c)
        return float(steps) / float(kwargs["gradient_steps"])

    def to_dict(self) -> dict[str, Any]:
        return {"ua2c": self.ua2c.to_dict(), "sb3_hyperparams": dict(self.sb3_hyperparams),
                "d3rlpy_batch_size": self.d3rlpy_batch_size, "calql_offline_steps": self.calql_offline_steps,
                "rlpd_updates_per_step": self.rlpd_updates_per_step, "iql_best_of_n": self.iql_best_of_n,
                "scenarios": self.scenarios, "peer_kwargs": {a: dict(k) for a, k in self.peer_kwargs.items()}}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> PeersBudget:
        """Inverse of :meth:`to_dict`; an unknown key raises ``ValueError`` naming it."""
        unknown = set(values) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown PeersBudget key(s) {sorted(unknown)}")
        values = {"scenarios": "figure2", **values}  # budgets recorded before the split: Figure 2's scenarios
        if "ua2c" in values:
            values["ua2c"] = Fig2Budget.from_dict(values["ua2c"])
        return cls(**values)

    def with_overrides(self, overrides: Mapping[str, Any]) -> PeersBudget:
        """A copy with ``overrides`` (``--budget``): PeersBudget keys replaced, ``"ua2c"``'s Fig2Budget keys one by
        one, ``"peer_kwargs"`` arm by arm; a bad key or value raises ``ValueError`` naming it."""
        values, overrides = self.to_dict(), dict(overrides)
        for key in ("ua2c", "peer_kwargs"):
            if not isinstance(overrides.get(key, {}), Mapping):
                raise ValueError(f"--budget: {key!r} must be an object, got {overrides[key]!r}")
            values[key] = {**values[key], **overrides.pop(key, {})}
        return PeersBudget.from_dict({**values, **overrides})

    def with_online_steps(self, online_steps: int) -> PeersBudget:
        """A copy with ``online_steps`` online env steps for every arm."""
        check_int("--online-steps", online_steps)
        return dataclasses.replace(self, ua2c=self.ua2c.replace(finetune_steps=online_steps))


#: Default: the Figure-2 dataset and offline budget (200 episodes, 6,000 gradient steps), 20 evaluation
#: episodes, and 5,000 online env steps for every arm (about two hours and fifty minutes for 5 seeds on 2 cores).
FULL_PEERS_BUDGET = PeersBudget()

#: ``--quick``: Figure 2's quick budget (4-s episodes, a few updates) and tiny peer networks.
QUICK_PEERS_BUDGET = PeersBudget(
    ua2c=QUICK_BUDGET,
    sb3_hyperparams={"learning_starts": 10, "batch_size": 8, "policy_kwargs": {"net_arch": [16]}},
    d3rlpy_batch_size=8,
)


@dataclass(frozen=True)
class PeerCostModel:
    """CPU cost of the peer units on one core, calibrated on ``experiments/peers/measure_costs.py`` (2026-12-02);
    RLPD's update on the tuning runs of 2026-12-04 (20.3–21.9 ms at 2, 4 and 8 updates per env step).

    :param sb3_update_ms: one SB3 gradient step with its env step (after ``learning_starts``), per arm
    :param sb3_env_ms: one SB3 env step without an update (the random ``learning_starts`` steps)
    :param d3rlpy_offline_ms: one d3rlpy offline gradient step, per arm
    :param d3rlpy_online_ms: one d3rlpy online env step with its update, per arm (RLPD: per update, times
        its updates per env step)
    :param eval_ms_per_step: evaluation, per env step
    """

    sb3_update_ms: Mapping[str, float] = field(
        default_factory=lambda: {"sac": 19.6, "tqc": 35.2, "crossq": 24.0, "sac_offline_mix": 19.6})
    sb3_env_ms: float = 0.5
    d3rlpy_offline_ms: Mapping[str, float] = field(
        default_factory=lambda: {"iql": 13.0, "calql": 125.6, "rebrac": 15.8, "bc": 3.6, "rlpd": 0.0})
    d3rlpy_online_ms: Mapping[str, float] = field(
        default_factory=lambda: {"iql": 30.7, "calql": 143.3, "rebrac": 35.1, "bc": 0.0, "rlpd": 21.0})
    eval_ms_per_step: float = 0.5


def _ua2c_schedule_defaults() -> dict[str, Any]:
    """UA2C's default ``train_freq`` and ``gradient_steps`` (its constructor's)."""
    import inspect

    from sb3_ua2c import UA2C

    params = inspect.signature(UA2C.__init__).parameters
    return {name: params[name].default for name in ("train_freq", "gradient_steps")}


def steps_per_episode(budget: Fig2Budget) -> float:
    """Env steps of a full episode: ``time_limit / step_length`` (40 s / 0.2 s = 200 by default)."""
    return float(budget.env_kwargs.get("time_limit", 40.0)) / float(budget.env_kwargs.get("step_length", 0.2))


def peer_unit_seconds(arm: str, budget: PeersBudget, costs: PeerCostModel | None = None) -> float:
    """Estimated CPU seconds of one peer unit (one arm, one seed)."""
    c = costs or PeerCostModel()
    ms = 1e-3
    n_evals = 1  # the final evaluation
    if arm in D3RLPY_ARMS and arm not in OFFLINE_ONLY_ARMS and budget.offline_steps(arm) > 0:
        n_evals += 1  # the offline policy's
    if arm == "iql" and budget.iql_best_of_n > 0:
        n_evals += 1  # the final policy acting by best-of-N
    evals = n_evals * budget.ua2c.eval_episodes * steps_per_episode(budget.ua2c)
    total = evals * c.eval_ms_per_step * ms
    if arm == "behaviour":
        return total
    if arm in D3RLPY_ARMS:
        total += budget.offline_steps(arm) * c.d3rlpy_offline_ms[arm] * ms
        online = 0 if arm in OFFLINE_ONLY_ARMS else budget.online_steps * budget.updates_per_step(arm)
        return total + online * c.d3rlpy_online_ms[arm] * ms
    starts = int(budget.sb3_kwargs(arm).get("learning_starts", 1000))
    updates = max(budget.online_steps - starts, 0)
    return total + (updates * c.sb3_update_ms[arm] + (budget.online_steps - updates) * c.sb3_env_ms) * ms


def ua2c_stage_seconds(budget: PeersBudget, costs: CostModel | None = None) -> dict[str, float]:
    """Estimated CPU seconds of one seed's UA2C units: ``dataset``, ``pretrain_k<k>`` and each UA2C arm
    (offline evaluation, online phase, final evaluation), with Figure 2's cost model."""
    c, b, ms = costs or CostModel(), budget.ua2c, 1e-3
    spe = steps_per_episode(b)
    out = {"dataset": b.dataset_episodes * spe * c.collect_ms_per_step * ms}
    scale = b.algo_kwargs.get("batch_size", 256) / 256
    for arm in UA2C_ARMS:
        k = budget.chunk_length(arm)
        extra = extra_kweights(budget.pretrain_kwargs(arm))
        out[budget.pretrain_name(arm)] = b.pretrain_steps * c.pretrain_step_ms(k, extra) * ms
        plan_length = 1.0 if k == 1 else float(k) if budget.delta(arm) == float("inf") else c.adaptive_plan_length
        online_ms = (c.finetune_ms_per_env_step + c.replan_ms(extra) / plan_length
                     + (c.finetune_ms_per_update * scale + extra * c.update_ms_per_kweight)
                     / budget.steps_per_update(arm, plan_length))
        eval_ms = c.eval_ms_per_step + extra / plan_length * c.plan_ms_per_kweight
        out[arm] = (budget.online_steps * online_ms + 2 * b.eval_episodes * spe * eval_ms) * ms
    return out


def estimate_units(budget: PeersBudget, arms: Sequence[str], n_seeds: int) -> dict[str, Any]:
    """CPU seconds per unit of each stage and arm (one seed), for :func:`format_estimate`.

    :return: ``{"dataset": s, "pretrain": {k: s}, "arms": {arm: s}}`` (``k``: ``"5"``, ``"5_paper"`` for the preset)
    """
    ua2c = ua2c_stage_seconds(budget)
    names = sorted({budget.pretrain_name(a) for a in arms if a in UA2C_ARMS})
    return {
        "seeds": n_seeds,
        "dataset": ua2c["dataset"],
        "pretrain": {name.removeprefix("pretrain_k"): ua2c[name] for name in names},  # "5", "5_paper"
        "arms": {a: ua2c[a] if a in UA2C_ARMS else peer_unit_seconds(a, budget) for a in arms},
    }


def estimate_wall(estimate: Mapping[str, Any], workers: int) -> dict[str, float]:
    """CPU and wall seconds of the whole run (every unit still to run) on ``workers`` local cores."""
    n = estimate["seeds"]
    stages = [[estimate["dataset"]] * n, list(estimate["pretrain"].values()) * n, list(estimate["arms"].values()) * n]
    cpu = sum(sum(s) for s in stages)
    # each stage's units longest first (run_peers submits them so)
    return {"cpu": cpu, "wall": sum(list_schedule_seconds(sorted(s, reverse=True), workers) for s in stages if s)}


def format_estimate(estimate: Mapping[str, Any], workers: int) -> str:
    """The estimate as printed before a run: per arm (one unit, all seeds) and in total."""
    n = estimate["seeds"]
    totals = estimate_wall(estimate, workers)
    lines = [f"estimate (CPU on one core per unit; {n} seed(s)):",
             f"  dataset {estimate['dataset'] / 60:.1f} min/seed; "
             + ", ".join(f"pretrain k={k} {s / 60:.1f} min/seed" for k, s in estimate["pretrain"].items())]
    for arm, s in estimate["arms"].items():
        lines.append(f"  {arm:22s} {s / 60:6.1f} min/unit  {s * n / 60:7.1f} min over seeds")
    lines.append(f"  total {totals['cpu'] / 60:.0f} CPU-min, ~{totals['wall'] / 60:.0f} min wall on {workers} "
                 "worker(s) (dedicated cores, before resuming)")
    return "\n".join(lines)
