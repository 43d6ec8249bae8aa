"""Budget and arms of the head-to-head, every arm of a seed on that seed's Figure-2 protocol."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from experiments.common.budget import Budget, Check, integer, mapping, one_of, optional
from experiments.common.estimate import estimate, recorded, seconds_per_size, wall_seconds
from experiments.common.names import SCENARIO_BASES
from experiments.fig2.budget import FULL_BUDGET, QUICK_BUDGET, Fig2Budget, finetune_overrides


@dataclass(frozen=True)
class UA2CArm:
    """How a UA2C arm is built from the budget (``"k"``, ``"delta"``, ``"budget"``: the budget's; ``None``: its
    checkpoint's; ``"paper"``: the preset)."""

    k: str | int = "k"
    delta: str | None = "delta"
    config: str = "budget"
    cadence: str = "fig2"


#: UA2C arms by name (``docs/peers.md``): as a user gets it, as the paper writes it, Figure 2's arms at the
#: defaults, and the adaptive arm at Figure 2's and at the peers' update cadence.
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


def _peer_kwargs(label: str, value: Any) -> None:
    mapping(label, value)
    for arm, kwargs in value.items():
        if arm not in (*PEER_ARMS, "bc"):
            raise ValueError(f"{label}: {arm!r} is not a peer arm; choose from {[*PEER_ARMS, 'bc']}")
        mapping(f"{label}[{arm!r}]", kwargs)


def _fig2_budget(label: str, value: Any) -> None:
    if not isinstance(value, Fig2Budget):
        raise TypeError(f"{label} must be a Fig2Budget, got {type(value).__name__}")


@dataclass(frozen=True)
class PeersBudget(Budget):
    """Budget of a head-to-head run (per seed); a bad value raises ``ValueError`` naming it."""

    #: the Figure-2 budget of the UA2C arms and of the shared inputs: dataset, offline steps (also the d3rlpy
    #: arms'), the online env steps of EVERY arm (``finetune_steps``), evaluation episodes
    ua2c: Fig2Budget = field(default_factory=lambda: FULL_BUDGET.replace(finetune_steps=5000))
    sb3_hyperparams: Mapping[str, Any] = field(default_factory=dict)  # over the zoo files', for every SB3 arm
    d3rlpy_batch_size: int = 256
    calql_offline_steps: int | None = None  # None: ua2c.pretrain_steps, like every other offline phase
    rlpd_updates_per_step: int = 4  # RLPD's update-to-data ratio (its paper: 20)
    scenarios: str = "test"  # the evaluation scenarios (SCENARIO_BASES): validation for choices, test to report
    iql_best_of_n: int = 32  # IQL also evaluated acting by the best of this many actions (0: not)
    #: per peer arm, hyperparameters on top of its defaults (a tuning configuration), e.g. {"iql": {"expectile": 0.9}}
    peer_kwargs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    CHECKS: ClassVar[Mapping[str, Check]] = {
        "ua2c": _fig2_budget, "sb3_hyperparams": mapping, "d3rlpy_batch_size": integer(),
        "calql_offline_steps": optional(integer()), "rlpd_updates_per_step": integer(), "iql_best_of_n": integer(low=0),
        "scenarios": one_of(*SCENARIO_BASES), "peer_kwargs": _peer_kwargs,
    }

    def validate(self) -> None:  # peer_kwargs in the arms' order, however given (a report prints them)
        kwargs = self.peer_kwargs
        object.__setattr__(self, "peer_kwargs", {a: kwargs[a] for a in (*PEER_ARMS, "bc") if a in kwargs})

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
        """The pre-trained checkpoint a UA2C arm starts from: ``pretrain_k<k>`` (``_paper`` for the preset)."""
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
        """Phase-2 attributes of a UA2C arm: its update cadence and, but for the preset, ``finetune_kwargs``."""
        spec = UA2C_ARMS[arm]
        if spec.cadence == "own":
            return {} if spec.config == "paper" else dict(self.ua2c.finetune_kwargs)
        overrides = finetune_overrides(self.ua2c)
        if spec.cadence == "per_step":
            overrides = {**overrides, "train_freq": 1, "gradient_steps": 1}  # same as default: the peers' cadence
        return overrides

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> PeersBudget:
        """:meth:`Budget.from_dict` (a budget recorded before the scenario split ran on Figure 2's scenarios)."""
        return super().from_dict({"scenarios": "figure2", **values})

    def with_overrides(self, overrides: Mapping[str, Any]) -> PeersBudget:
        """A copy with ``overrides`` (``--budget``): keys replaced, those of ``"ua2c"`` and ``"peer_kwargs"`` one by one."""
        values, overrides = self.to_dict(), dict(overrides)
        for key in ("ua2c", "peer_kwargs"):
            if not isinstance(overrides.get(key, {}), Mapping):
                raise ValueError(f"--budget: {key!r} must be an object, got {overrides[key]!r}")
            values[key] = {**values[key], **overrides.pop(key, {})}
        return PeersBudget.from_dict({**values, **overrides})

    def with_online_steps(self, online_steps: int) -> PeersBudget:
        """A copy with ``online_steps`` online env steps for every arm."""
        integer()("--online-steps", online_steps)
        return dataclasses.replace(self, ua2c=self.ua2c.replace(finetune_steps=online_steps))


#: Default: the Figure-2 dataset and offline budget, 20 evaluation episodes, 5,000 online env steps for every arm.
FULL_PEERS_BUDGET = PeersBudget()

#: ``--quick``: Figure 2's quick budget (4-s episodes, a few updates) and tiny peer networks.
QUICK_PEERS_BUDGET = PeersBudget(
    ua2c=QUICK_BUDGET, sb3_hyperparams={"learning_starts": 10, "batch_size": 8, "policy_kwargs": {"net_arch": [16]}},
    d3rlpy_batch_size=8)


def unit_steps(budget: PeersBudget, arm: str) -> float:
    """What one unit of ``arm`` costs in proportion to: its offline and online steps (at least 1)."""
    return max(budget.offline_steps(arm) + (0 if arm in REFERENCE_ARMS else budget.online_steps), 1)


def estimate_units(budget: PeersBudget, arms: Sequence[str], n_seeds: int, workers: int,
                   records: Sequence[Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """CPU seconds of one unit of each arm from the ``records`` (default: the committed ones), and the run's."""
    records = recorded("**/peers_raw/seed*/*.json") if records is None else records
    rates = seconds_per_size((r["arm"], r["cpu_seconds"]["total"], max(r.get("offline_steps", 0) + r["online_steps"], 1))
                             for r in records if "cpu_seconds" in r)
    per_unit = estimate(rates, {arm: unit_steps(budget, arm) for arm in arms})
    units = [s for s in per_unit.values() for _ in range(n_seeds)]
    return {"cpu": sum(units), "wall": wall_seconds(units, workers), "workers": workers, "per_unit": per_unit}


def format_estimate(estimate: Mapping[str, Any]) -> str:
    """The estimate as printed before a run: per arm (one unit) and in total."""
    head = (f"peers: estimated {estimate['cpu'] / 60:.0f} CPU-min, ~{estimate['wall'] / 60:.0f} min wall on "
            f"{estimate['workers']} worker(s) (from the unit times of the committed records; before resuming)")
    lines = [f"  {arm:22s} {s / 60:6.1f} CPU-min per unit" for arm, s in estimate["per_unit"].items()]
    return "\n".join([head, *lines])
