"""UA2C's hyperparameters: the execution rule (:class:`ExecutionRule`, one frozen object that checks
itself), the one validator of the other arguments of :class:`~sb3_ua2c.ua2c.UA2C`,
:class:`~sb3_ua2c.policies.UA2CPolicy` and :class:`~sb3_ua2c.buffers.ChunkReplayBuffer`
(:func:`check_arguments`), and the checks of the spaces and of ``policy_kwargs``.

Each hyperparameter is declared once, as a constructor argument; its check lives here, once.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_ua2c.actors import ACTORS
from sb3_ua2c.checks import check_bool, check_int, check_net_arch
from sb3_ua2c.chunking import SELECTIONS
from sb3_ua2c.critics import CRITICS
from sb3_ua2c.exploration import EXPLORATIONS
from sb3_ua2c.extraction import ACTOR_EXTRACTIONS
from sb3_ua2c.targets import CRITIC_TARGETS

#: values of ``ExecutionRule.rule`` (UA2C's ``execution_rule``): how ``L_t`` is set from the entropies ``H_u``
EXECUTION_RULES = ("threshold", "quantile", "growth", "replan", "ensemble")
#: ``q`` of ``execution_rule="quantile"`` when ``entropy_quantile`` is not given
DEFAULT_ENTROPY_QUANTILE = 0.75
#: ``c`` (nats above ``H_1``) of ``execution_rule="growth"`` when ``entropy_growth`` is not given
DEFAULT_ENTROPY_GROWTH = 0.5
#: ``m`` of ``execution_rule="ensemble"``: the weight of a chunk's action is ``exp(-m i)``, ``i = 0`` the oldest
#: chunk (ACT's temporal ensembling, Zhao et al., 2023, and its default)
DEFAULT_ENSEMBLE_DECAY = 0.01

#: values of ``online_targets`` (:class:`~sb3_ua2c.buffers.ChunkReplayBuffer`, ``UA2C``)
ONLINE_TARGETS = ("auto", "prefix", "window")

#: arguments of a policy class that are not hyperparameters (the spaces, and what SB3 passes itself)
_POLICY_PLUMBING = ("self", "observation_space", "action_space", "lr_schedule")


def _is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float | np.number) and not math.isnan(value)


def _positive_int(name: str, value: Any) -> None:
    check_int(name, value)


def _non_negative_int(name: str, value: Any) -> None:
    check_int(name, value, low=0)


def _non_negative_number(name: str, value: Any) -> None:
    if not _is_number(value) or not 0.0 <= value < math.inf:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


def _fraction(name: str, value: Any) -> None:
    if not _is_number(value) or not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}")


def _tau(name: str, value: Any) -> None:
    if not _is_number(value) or not 0.0 < value <= 1.0:
        raise ValueError(f"{name} must be a number in (0, 1], got {value!r}")


def _learning_rate(name: str, value: Any) -> None:
    if not callable(value) and (not _is_number(value) or not 0.0 <= value < math.inf):
        raise ValueError(f"{name} must be a finite number >= 0 or a schedule, got {value!r}")


def _one_of(choices: Sequence[str] | Mapping[str, Any]) -> Callable[[str, Any], None]:
    def check(name: str, value: Any) -> None:
        if not isinstance(value, str) or value not in choices:
            raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")

    return check


def _net_arch(name: str, value: Any) -> None:
    if value is not None:
        check_net_arch(name, value)


def _must_be_false(name: str, value: Any) -> None:
    if value is not False:
        raise ValueError(f"{name} must be False (UA2C flattens Box observations as they are), got {value!r}")


def _discrete_action_dims(name: str, value: Any) -> None:
    normalize_discrete_dims(value, action_dim=None)


def _subclass_of(base: type) -> Callable[[str, Any], None]:
    def check(name: str, value: Any) -> None:
        if not (isinstance(value, type) and issubclass(value, base)):
            raise ValueError(f"{name} must be a subclass of {base.__module__}.{base.__qualname__}, got {value!r}")

    return check


def _optional_dict(name: str, value: Any) -> None:
    if value is not None and not isinstance(value, Mapping):
        raise ValueError(f"{name} must be a dict or None, got {value!r}")


#: the check of every hyperparameter, by name (each raises ``ValueError`` naming it)
_CHECKS: dict[str, Callable[[str, Any], None]] = {
    # SB3's arguments of UA2C
    "learning_rate": _learning_rate,
    "buffer_size": _positive_int,
    "learning_starts": _non_negative_int,
    "batch_size": _positive_int,
    "tau": _tau,
    "gamma": _fraction,
    # UA2C
    "chunk_size": _positive_int,
    "history_len": _positive_int,
    "flow_steps": _positive_int,
    "target_flow_steps": _positive_int,
    "n_candidates": _positive_int,
    "n_target_candidates": _positive_int,
    "q_weight": _non_negative_number,
    "smooth_weight": _non_negative_number,
    "discrete_entropy": check_bool,
    "commit_discrete": check_bool,
    "discrete_action_dims": _discrete_action_dims,
    "past_action_dropout": _fraction,
    "normalize_q": check_bool,
    "distill_weight": _non_negative_number,
    "offline_ratio": _fraction,
    "online_targets": _one_of(ONLINE_TARGETS),
    "critic_target": _one_of(CRITIC_TARGETS),
    "critic_target_kwargs": _optional_dict,  # checked by the target class (:func:`~sb3_ua2c.registry.build`)
    "actor_extraction": _one_of(ACTOR_EXTRACTIONS),
    "actor_extraction_kwargs": _optional_dict,  # checked by the extraction class
    "exploration": _one_of(EXPLORATIONS),
    "exploration_kwargs": _optional_dict,  # checked by the exploration class
    # UA2CPolicy's networks and acting rule
    "selection": _one_of(SELECTIONS),
    "n_elite": _positive_int,
    "net_arch": _net_arch,
    "actor_type": _one_of(ACTORS),  # the registries as they are when checked
    "actor_past_actions": check_bool,
    "critic_arch": _one_of(CRITICS),
    "critic_kwargs": _optional_dict,  # checked by the critic class (:func:`~sb3_ua2c.critics.make_critic`)
    "n_critics": _positive_int,
    "activation_fn": _subclass_of(th.nn.Module),
    "optimizer_class": _subclass_of(th.optim.Optimizer),
    "optimizer_kwargs": _optional_dict,
    "torch_compile": check_bool,
    "normalize_images": _must_be_false,
    "value_arch": _optional_dict,
}


def check_arguments(**arguments: Any) -> None:
    """
    The one validator of UA2C's hyperparameters: check every argument given (by name, as the
    constructors spell them) and the constraints between those given together. A bad value raises a
    ``ValueError`` that names the parameter.

    Constraints between arguments: ``n_elite <= n_candidates``; ``selection="uncertainty"`` needs
    ``n_critics >= 2``; an ``actor_extraction`` that reads the
    in-sample value (``"awr"``) needs a ``critic_target`` that fits one (``"in_sample"``) and an
    ``actor_type`` it trains (``"flow"``). The execution rule checks itself (:class:`ExecutionRule`), a
    critic, target, extraction or exploration class its ``*_kwargs``.

    :param arguments: hyperparameters by name (any subset of the constructors' arguments)
    """
    for name, value in arguments.items():
        if name not in _CHECKS:
            raise ValueError(f"unknown UA2C hyperparameter {name!r}")
        _CHECKS[name](name, value)
    if "n_elite" in arguments and "n_candidates" in arguments and arguments["n_elite"] > arguments["n_candidates"]:
        raise ValueError(f"n_elite={arguments['n_elite']} must not exceed n_candidates={arguments['n_candidates']}")
    if arguments.get("selection") == "uncertainty" and arguments.get("n_critics", 2) < 2:
        raise ValueError(f"selection='uncertainty' weighs the candidates by the critics' disagreement: it needs "
                         f"n_critics >= 2, got n_critics={arguments['n_critics']}")
    _check_extraction(arguments)


def _check_extraction(arguments: Mapping[str, Any]) -> None:
    """The constraints of ``actor_extraction`` with ``critic_target`` and ``actor_type``, when given together."""
    if "actor_extraction" not in arguments:
        return
    extraction = ACTOR_EXTRACTIONS[arguments["actor_extraction"]]
    target = arguments.get("critic_target")
    if extraction.needs_value and target is not None and not CRITIC_TARGETS[target].fits_value:
        raise ValueError(
            f"actor_extraction={arguments['actor_extraction']!r} weights the data's chunks by their advantage "
            f"over the in-sample value V, which critic_target={target!r} does not fit: use "
            f"critic_target='in_sample'"
        )
    actor_type = arguments.get("actor_type")
    if actor_type is not None and extraction.actor_types is not None and actor_type not in extraction.actor_types:
        raise ValueError(
            f"actor_extraction={arguments['actor_extraction']!r} trains actor_type in {list(extraction.actor_types)} "
            f"only, got actor_type={actor_type!r} (its objective is a value term, which this extraction replaces)"
        )


def normalize_discrete_dims(
    discrete_action_dims: Mapping[int, Sequence[float]] | None, action_dim: int | None
) -> dict[int, int]:
    """
    Validate ``discrete_action_dims`` and return ``{dim: n_categories}``.

    A categorical action dimension with ``n`` values is encoded, like the traffic environment's lane
    change, by ``n`` equal-width bins over its Box bounds (3 values over [-1, 1] -> thresholds ±1/3);
    the i-th value corresponds to the i-th bin.

    :param discrete_action_dims: mapping ``action index -> increasing category values`` (or ``None``);
        an index may be a string of digits (JSON, as in a saved model, turns integer keys into strings)
    :param action_dim: number of action dimensions (``None``: the indices are not bounded above)
    :return: mapping ``action index -> number of categories``
    """
    if discrete_action_dims is None:
        return {}
    if not isinstance(discrete_action_dims, Mapping):
        raise ValueError(
            "discrete_action_dims must be a mapping {action index: category values}, "
            f"got {type(discrete_action_dims).__name__}"
        )
    out: dict[int, int] = {}
    for dim, values in discrete_action_dims.items():
        if isinstance(dim, str) and dim.isdigit():
            dim = int(dim)
        upper = math.inf if action_dim is None else action_dim
        if isinstance(dim, bool) or not isinstance(dim, int | np.integer) or not 0 <= int(dim) < upper:
            raise ValueError(f"discrete_action_dims: action index {dim!r} is not in [0, {upper})")
        vals = [float(v) for v in values]
        if len(vals) < 2:
            raise ValueError(f"discrete_action_dims[{dim}] needs at least 2 category values, got {vals}")
        if any(b <= a for a, b in zip(vals, vals[1:], strict=False)):
            raise ValueError(f"discrete_action_dims[{dim}] values must be strictly increasing, got {vals}")
        out[int(dim)] = len(vals)
    return out


def check_spaces(observation_space: spaces.Space | None, action_space: spaces.Space | None) -> None:
    """Raise ``ValueError`` unless both spaces are ``Box`` spaces and the action space is bounded."""
    if action_space is not None and not isinstance(action_space, spaces.Box):
        raise ValueError(f"UA2C supports Box action spaces only, got {type(action_space).__name__}")
    if observation_space is not None and not isinstance(observation_space, spaces.Box):
        raise ValueError(f"UA2C supports Box observation spaces only, got {type(observation_space).__name__}")
    if isinstance(action_space, spaces.Box) and not (
        np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))
    ):
        raise ValueError("UA2C needs a bounded Box action space (finite low and high)")


def _model_arguments(model_class: type) -> set[str]:
    """What a model passes to its policy itself: its constructor's arguments, ``execution`` (the
    :class:`ExecutionRule` it builds from its execution-rule arguments) and ``value_arch`` (from its
    ``critic_target``)."""
    return set(inspect.signature(model_class.__init__).parameters) | {"execution", "value_arch"}


def policy_kwargs_names(policy_class: type, model_class: type) -> tuple[str, ...]:
    """
    The arguments of ``policy_class`` that ``policy_kwargs`` may set: its constructor's arguments without
    the spaces and the schedule, and without those the model passes itself (:func:`_model_arguments`).
    """
    model = _model_arguments(model_class)
    names = inspect.signature(policy_class.__init__).parameters
    return tuple(p for p in names if p not in _POLICY_PLUMBING and p not in model)


def check_policy_kwargs(policy_kwargs: Mapping[str, Any] | None, policy_class: type, model_class: type) -> None:
    """
    Raise ``ValueError`` naming a key of ``policy_kwargs`` that the model sets from its own argument, or
    that is not an argument of ``policy_class`` (:func:`policy_kwargs_names`).
    """
    allowed, model = policy_kwargs_names(policy_class, model_class), _model_arguments(model_class)
    for key in policy_kwargs or {}:
        if key in model:
            raise ValueError(f"policy_kwargs[{key!r}] is set by UA2C's own argument; pass it to UA2C(...) instead")
        if key not in allowed:
            raise ValueError(f"unknown policy_kwargs key {key!r}; allowed: {sorted(allowed)}")


@dataclass(frozen=True)
class ExecutionRule:
    """
    The execution rule: how the executed length ``L_t`` of a replanning follows from the per-position
    entropies ``H_u`` of its candidates (docs/algorithm.md). It acts only when acting: the losses do not
    read it. One frozen object, checked when it is built (a bad field raises a ``ValueError`` that names
    it), held by the policy (:attr:`UA2CPolicy.execution <sb3_ua2c.policies.UA2CPolicy>`) and saved with
    the model. :class:`~sb3_ua2c.ua2c.UA2C` builds it from its arguments ``execution_rule``,
    ``entropy_threshold``, ``target_plan_length``, ``entropy_quantile`` and ``entropy_growth``; change it
    with :meth:`UA2C.set_execution_rule <sb3_ua2c.ua2c.UA2C.set_execution_rule>` (e.g.
    ``model.set_execution_rule(dataclasses.replace(model.execution, entropy_threshold=math.inf))``).

    A parameter of one rule set to other than its default under another rule is an error.

    :param rule: UA2C's ``execution_rule``: ``"threshold"`` (default, Eq. 7): the longest prefix with
        every ``H_u <= entropy_threshold``; ``"quantile"`` (not in the paper): Eq. 7 with per-position
        thresholds ``delta_u``, the ``entropy_quantile`` of ``H_u`` over histories of the data, calibrated
        by :meth:`~sb3_ua2c.ua2c.UA2C.calibrate_execution` and saved with the model; ``"growth"`` (not in
        the paper): the longest prefix with every ``H_u - H_1 <= entropy_growth``; ``"replan"``: one action of
        each chunk, then a new chunk (receding horizon, ``L_t = 1``); ``"ensemble"``: a new chunk at every step
        and the action the weighted mean of what the last ``k`` chunks planned for this step (temporal
        ensembling as in ACT, Zhao et al., 2023; weights ``exp(-ensemble_decay * i)``, ``i = 0`` the oldest)
    :param entropy_threshold: ``delta`` of Eq. 7 in nats (``math.inf`` = the whole chunk: fixed chunk
        execution), or ``"auto"``: δ set after each training replanning from the entropies of the last
        ones, for a mean ``L_t`` of ``target_plan_length`` (:func:`~sb3_ua2c.chunking.auto_entropy_threshold`)
    :param target_plan_length: with ``entropy_threshold="auto"`` only: the target mean ``L_t`` in
        ``[1, k]`` (``None`` = ``(k + 1) / 2``)
    :param entropy_quantile: with ``rule="quantile"`` only: ``q`` in ``[0, 1]``, a fraction of states
        (``None`` = :data:`DEFAULT_ENTROPY_QUANTILE`)
    :param entropy_growth: with ``rule="growth"`` only: ``c`` in nats above ``H_1`` (``None`` =
        :data:`DEFAULT_ENTROPY_GROWTH`)
    :param ensemble_decay: with ``rule="ensemble"`` only: ``m >= 0`` of the weights ``exp(-m i)``
        (:data:`DEFAULT_ENSEMBLE_DECAY`, ACT's; 0 = the plain mean of the overlapping chunks)
    """

    rule: str = "threshold"
    entropy_threshold: float | str = 0.0
    target_plan_length: float | None = None
    entropy_quantile: float | None = None
    entropy_growth: float | None = None
    ensemble_decay: float = DEFAULT_ENSEMBLE_DECAY

    def __post_init__(self) -> None:
        if not isinstance(self.rule, str) or self.rule not in EXECUTION_RULES:
            raise ValueError(f"execution_rule (ExecutionRule.rule) must be one of {list(EXECUTION_RULES)}, "
                             f"got {self.rule!r}")
        delta = self.entropy_threshold
        if not (delta == "auto" if isinstance(delta, str) else _is_number(delta)):
            raise ValueError(f"entropy_threshold must be a number or 'auto', got {delta!r}")
        if delta == -math.inf:
            raise ValueError("entropy_threshold must not be -inf (one action per plan is "
                             "execution_rule='replan')")
        if self.target_plan_length is not None and not _is_number(self.target_plan_length):
            raise ValueError(f"target_plan_length must be a number or None, got {self.target_plan_length!r}")
        if self.entropy_quantile is not None:
            _fraction("entropy_quantile", self.entropy_quantile)
        if self.entropy_growth is not None:
            _non_negative_number("entropy_growth", self.entropy_growth)
        _non_negative_number("ensemble_decay", self.ensemble_decay)
        self._check_rule_parameters()
        if self.target_plan_length is not None:
            if delta != "auto":
                raise ValueError(
                    f"target_plan_length applies to entropy_threshold='auto' only, got it with "
                    f"entropy_threshold={delta!r} (pass target_plan_length=None)"
                )
            self.check_chunk_size(math.inf)

    def _check_rule_parameters(self) -> None:
        """A rule's parameter set (not at its default) under another rule is an error."""
        other_rules = (
            ("threshold", "entropy_threshold"),
            ("threshold", "target_plan_length"),
            ("quantile", "entropy_quantile"),
            ("growth", "entropy_growth"),
            ("ensemble", "ensemble_decay"),
        )
        for rule, name in other_rules:
            value, unset = getattr(self, name), ExecutionRule.__dataclass_fields__[name].default
            if rule != self.rule and value != unset:
                raise ValueError(
                    f"{name} applies to execution_rule={rule!r} only, got {name}={value!r} with "
                    f"execution_rule={self.rule!r} (leave {name} at {unset!r})"
                )

    def check_chunk_size(self, chunk_size: float) -> None:
        """
        Raise ``ValueError`` unless ``target_plan_length`` (when set) lies in ``[1, chunk_size]``.

        :param chunk_size: ``k`` of the policy that acts with this rule
        """
        target = self.target_plan_length
        if target is not None and not 1 <= target <= chunk_size:
            raise ValueError(f"target_plan_length must be a number in [1, chunk_size={chunk_size}], got {target!r}")

    @property
    def auto(self) -> bool:
        """δ set from the recent entropies (``entropy_threshold="auto"`` under ``rule="threshold"``)."""
        return self.rule == "threshold" and self.entropy_threshold == "auto"

    @property
    def quantile(self) -> float:
        """``q`` of ``rule="quantile"`` (:data:`DEFAULT_ENTROPY_QUANTILE` when not given)."""
        return DEFAULT_ENTROPY_QUANTILE if self.entropy_quantile is None else self.entropy_quantile

    @property
    def growth(self) -> float:
        """``c`` of ``rule="growth"`` (:data:`DEFAULT_ENTROPY_GROWTH` when not given)."""
        return DEFAULT_ENTROPY_GROWTH if self.entropy_growth is None else self.entropy_growth


def make_execution_rule(execution_rule: str | ExecutionRule | None, **fields: Any) -> ExecutionRule:
    """
    The :class:`ExecutionRule` of UA2C's arguments: ``execution_rule`` itself when it is one, else a rule
    of that name (``None``: the rule's default) with the fields given; a ``None`` field stands for the
    :class:`ExecutionRule`'s default, the one home of each.

    :param execution_rule: an :class:`ExecutionRule`, a name of :data:`EXECUTION_RULES`, or ``None``
    :param fields: ``entropy_threshold``, ``target_plan_length``, ``entropy_quantile``, ``entropy_growth``
        (``None``: not given); any of them given with an :class:`ExecutionRule` raises a ``ValueError``
        naming it
    :return: the rule (checked)
    """
    given = {name: value for name, value in fields.items() if value is not None}
    if isinstance(execution_rule, ExecutionRule):
        if given:
            name = sorted(given)[0]
            raise ValueError(f"{name}={given[name]!r} cannot be given with execution_rule=ExecutionRule(...): "
                             f"set it in the ExecutionRule")
        return execution_rule
    return ExecutionRule(**given) if execution_rule is None else ExecutionRule(execution_rule, **given)


__all__ = [
    "DEFAULT_ENSEMBLE_DECAY",
    "DEFAULT_ENTROPY_GROWTH",
    "DEFAULT_ENTROPY_QUANTILE",
    "EXECUTION_RULES",
    "ONLINE_TARGETS",
    "ExecutionRule",
    "check_arguments",
    "check_policy_kwargs",
    "check_spaces",
    "make_execution_rule",
    "normalize_discrete_dims",
    "policy_kwargs_names",
]
