"""UA2C's hyperparameters: the one validator of every argument of :class:`~sb3_ua2c.ua2c.UA2C`,
:class:`~sb3_ua2c.policies.UA2CPolicy` and :class:`~sb3_ua2c.buffers.ChunkReplayBuffer`
(:func:`check_arguments`), the list of the policy's chunking arguments that UA2C forwards to it
(:data:`POLICY_CHUNKING_ARGUMENTS`), and the checks of the spaces and of ``policy_kwargs``.

Each hyperparameter is declared once, as a constructor argument; its check lives here, once.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_ua2c.checks import check_bool, check_int

#: The chunking arguments of :class:`~sb3_ua2c.policies.UA2CPolicy`. UA2C takes each of them as a
#: constructor argument of its own and forwards it to the policy; ``policy_kwargs`` may not set them.
POLICY_CHUNKING_ARGUMENTS = (
    "chunk_size",
    "history_len",
    "flow_steps",
    "n_candidates",
    "execution_rule",
    "entropy_threshold",
    "target_plan_length",
    "entropy_quantile",
    "entropy_growth",
    "discrete_action_dims",
    "discrete_entropy",
    "commit_discrete",
)

#: values of ``execution_rule``: how ``L_t`` is set from the entropies ``H_u`` (:class:`~sb3_ua2c.ua2c.UA2C`)
EXECUTION_RULES = ("threshold", "quantile", "growth")
#: the arguments that make up the execution rule, with their defaults (``None``: the rule's own default)
EXECUTION_RULE_DEFAULTS: dict[str, Any] = {
    "execution_rule": "threshold",
    "entropy_threshold": 0.0,
    "target_plan_length": None,
    "entropy_quantile": None,
    "entropy_growth": None,
}
#: ``q`` of ``execution_rule="quantile"`` when ``entropy_quantile`` is not given
DEFAULT_ENTROPY_QUANTILE = 0.75
#: ``c`` (nats above ``H_1``) of ``execution_rule="growth"`` when ``entropy_growth`` is not given
DEFAULT_ENTROPY_GROWTH = 0.5

#: values of ``online_targets`` (:class:`~sb3_ua2c.buffers.ChunkReplayBuffer`, ``UA2C``)
ONLINE_TARGETS = ("auto", "prefix", "window")
#: the critic architectures (``critic_arch``): the paper's per-token Transformer, or an MLP over the
#: flattened history and chunk (see :mod:`sb3_ua2c.networks`)
CRITIC_ARCHS = ("transformer", "mlp")

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


def _entropy_threshold(name: str, value: Any) -> None:
    if not (value == "auto" if isinstance(value, str) else _is_number(value)):
        raise ValueError(f"{name} must be a number or 'auto', got {value!r}")
    if value == -math.inf:
        raise ValueError(f"{name} must not be -inf (it would execute one action per plan: use chunk_size=1)")


def _one_of(choices: Sequence[str]) -> Callable[[str, Any], None]:
    def check(name: str, value: Any) -> None:
        if not isinstance(value, str) or value not in choices:
            raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")

    return check


def _optional_fraction(name: str, value: Any) -> None:
    if value is not None:
        _fraction(name, value)


def _optional_non_negative_number(name: str, value: Any) -> None:
    if value is not None:
        _non_negative_number(name, value)


def _optional_number(name: str, value: Any) -> None:
    if value is not None and not _is_number(value):
        raise ValueError(f"{name} must be a number or None, got {value!r}")


def _net_arch(name: str, value: Any) -> None:
    if value is None:
        return
    if not isinstance(value, Sequence) or not value or any(not _is_number(h) or int(h) != h or h < 1 for h in value):
        raise ValueError(f"{name} must be a non-empty list of positive integers, got {value!r}")


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
    "execution_rule": _one_of(EXECUTION_RULES),
    "entropy_threshold": _entropy_threshold,
    "target_plan_length": _optional_number,
    "entropy_quantile": _optional_fraction,
    "entropy_growth": _optional_non_negative_number,
    "q_weight": _non_negative_number,
    "smooth_weight": _non_negative_number,
    "discrete_entropy": check_bool,
    "commit_discrete": check_bool,
    "discrete_action_dims": _discrete_action_dims,
    "offline_ratio": _fraction,
    "online_targets": _one_of(ONLINE_TARGETS),
    # UA2CPolicy's networks and acting rule
    "n_elite": _positive_int,
    "net_arch": _net_arch,
    "critic_arch": _one_of(CRITIC_ARCHS),
    "critic_embed_dim": _positive_int,
    "critic_n_layers": _positive_int,
    "critic_n_heads": _positive_int,
    "critic_ff_dim": _positive_int,
    "critic_net_arch": _net_arch,
    "critic_layer_norm": check_bool,
    "n_critics": _positive_int,
    "activation_fn": _subclass_of(th.nn.Module),
    "optimizer_class": _subclass_of(th.optim.Optimizer),
    "optimizer_kwargs": _optional_dict,
    "torch_compile": check_bool,
    "normalize_images": _must_be_false,
}


def check_arguments(**arguments: Any) -> None:
    """
    The one validator of UA2C's hyperparameters: check every argument given (by name, as the
    constructors spell them) and the constraints between those given together. A bad value raises a
    ``ValueError`` that names the parameter.

    Constraints between arguments: a parameter of an execution rule is set only with that rule
    (``entropy_threshold`` other than 0 and ``target_plan_length`` with ``"threshold"``,
    ``entropy_quantile`` with ``"quantile"``, ``entropy_growth`` with ``"growth"``);
    ``target_plan_length`` (not ``None``) needs ``entropy_threshold="auto"`` and lies in
    ``[1, chunk_size]``; ``n_elite <= n_candidates``; ``critic_n_heads`` divides ``critic_embed_dim``.

    :param arguments: hyperparameters by name (any subset of the constructors' arguments)
    """
    for name, value in arguments.items():
        if name not in _CHECKS:
            raise ValueError(f"unknown UA2C hyperparameter {name!r}")
        _CHECKS[name](name, value)
    _check_rule_parameters(arguments)
    target = arguments.get("target_plan_length")
    if target is not None:
        delta = arguments.get("entropy_threshold")
        if delta != "auto":
            raise ValueError(
                f"target_plan_length applies to entropy_threshold='auto' only, got it with "
                f"entropy_threshold={delta!r} (pass target_plan_length=None)"
            )
        k = arguments.get("chunk_size", math.inf)
        if not 1 <= target <= k:
            raise ValueError(f"target_plan_length must be a number in [1, chunk_size={k}], got {target!r}")
    if "n_elite" in arguments and "n_candidates" in arguments and arguments["n_elite"] > arguments["n_candidates"]:
        raise ValueError(f"n_elite={arguments['n_elite']} must not exceed n_candidates={arguments['n_candidates']}")
    if arguments.get("critic_net_arch") is not None and arguments.get("critic_arch", "transformer") != "mlp":
        raise ValueError(
            f"critic_net_arch applies to critic_arch='mlp' only, got it with critic_arch="
            f"{arguments.get('critic_arch', 'transformer')!r}"
        )
    if "critic_embed_dim" in arguments and arguments["critic_embed_dim"] % arguments.get("critic_n_heads", 1):
        raise ValueError(
            f"critic_n_heads={arguments['critic_n_heads']} must divide critic_embed_dim={arguments['critic_embed_dim']}"
        )


#: the parameters of each execution rule (their defaults in :data:`EXECUTION_RULE_DEFAULTS` mean "not set")
_RULE_PARAMETERS = {
    "threshold": ("entropy_threshold", "target_plan_length"),
    "quantile": ("entropy_quantile",),
    "growth": ("entropy_growth",),
}


def _check_rule_parameters(arguments: Mapping[str, Any]) -> None:
    """A rule's parameter set (not at its "not set" value) under another ``execution_rule`` is an error."""
    rule = arguments.get("execution_rule")
    if rule is None:
        return
    for other, parameters in _RULE_PARAMETERS.items():
        for name in parameters:
            unset = EXECUTION_RULE_DEFAULTS[name]
            if other != rule and name in arguments and arguments[name] != unset:
                raise ValueError(
                    f"{name} applies to execution_rule={other!r} only, got {name}={arguments[name]!r} with "
                    f"execution_rule={rule!r} (leave {name} at {unset!r})"
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


def hyperparameters(obj: Any, cls: type | None = None) -> dict[str, Any]:
    """
    The hyperparameters of ``cls`` (default ``type(obj)``) as ``obj`` holds them: every constructor
    argument that :func:`check_arguments` knows, read from the attribute of the same name.
    """
    names = inspect.signature((cls or type(obj)).__init__).parameters
    return {name: getattr(obj, name) for name in names if name in _CHECKS}


def policy_arguments(policy_class: type) -> tuple[str, ...]:
    """The hyperparameters of a policy class: its constructor's arguments without the spaces and the schedule."""
    return tuple(p for p in inspect.signature(policy_class.__init__).parameters if p not in _POLICY_PLUMBING)


def check_policy_kwargs(policy_kwargs: Mapping[str, Any] | None, policy_class: type) -> None:
    """
    Raise ``ValueError`` naming a key of ``policy_kwargs`` that is not an argument of ``policy_class``,
    or that UA2C sets from its own argument (:data:`POLICY_CHUNKING_ARGUMENTS`).
    """
    allowed = [p for p in policy_arguments(policy_class) if p not in POLICY_CHUNKING_ARGUMENTS]
    for key in policy_kwargs or {}:
        if key in POLICY_CHUNKING_ARGUMENTS:
            raise ValueError(f"policy_kwargs[{key!r}] is set by UA2C's own argument; pass it to UA2C(...) instead")
        if key not in allowed:
            raise ValueError(f"unknown policy_kwargs key {key!r}; allowed: {sorted(allowed)}")


__all__ = [
    "DEFAULT_ENTROPY_GROWTH",
    "DEFAULT_ENTROPY_QUANTILE",
    "EXECUTION_RULE_DEFAULTS",
    "EXECUTION_RULES",
    "ONLINE_TARGETS",
    "POLICY_CHUNKING_ARGUMENTS",
    "check_arguments",
    "check_policy_kwargs",
    "check_spaces",
    "hyperparameters",
    "normalize_discrete_dims",
    "policy_arguments",
]
