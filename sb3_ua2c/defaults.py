"""The defaults of UA2C's hyperparameters, read from where they are declared.

Each default is written once: in the constructor signature of :class:`~sb3_ua2c.ua2c.UA2C` or
:class:`~sb3_ua2c.policies.UA2CPolicy`, or, where the signature says ``None`` ("the default"), in the
one constant or dataclass that argument documents (:data:`~sb3_ua2c.policies.DEFAULT_N_ELITE`,
:class:`~sb3_ua2c.config.ExecutionRule`, ...), and for a critic's own arguments (``critic_kwargs``) in
the signature of its class (:data:`~sb3_ua2c.critics.CRITICS`), as for the options' own arguments
(``critic_target_kwargs``, ``actor_extraction_kwargs``, ``exploration_kwargs``: the signature of the
chosen class, :mod:`sb3_ua2c.registry`). Presets, the zoo's YAML files and the research
harnesses take a default from :func:`defaults` instead of writing it again, and the tests compare
every configuration that states a value against it.
"""

from __future__ import annotations

import copy
import inspect
from typing import Any


def _signature_defaults(cls: type, skip: tuple[str, ...]) -> dict[str, Any]:
    params = inspect.signature(cls.__init__).parameters  # type: ignore[misc]
    return {
        name: p.default
        for name, p in params.items()
        if name not in skip and p.default is not inspect.Parameter.empty and not name.startswith("_")
    }


def defaults() -> dict[str, Any]:
    """
    The value every hyperparameter of UA2C takes when it is not given: ``UA2C``'s constructor
    arguments by name, and ``policy_kwargs`` as the dict of :class:`~sb3_ua2c.policies.UA2CPolicy`'s
    own arguments. An argument whose signature default is ``None`` but stands for a value (``n_elite``,
    ``net_arch``, ``critic_kwargs``, the execution rule's fields, the options' ``*_kwargs``, ...) is given
    that value, as :func:`~sb3_ua2c.policies.resolved_policy_defaults`, :class:`~sb3_ua2c.config.ExecutionRule`
    and :func:`~sb3_ua2c.registry.resolved_kwargs` resolve it.

    :return: a fresh dict (changing it changes nothing else)
    """
    from sb3_ua2c.config import ExecutionRule, policy_kwargs_names
    from sb3_ua2c.options import OPTIONS
    from sb3_ua2c.policies import UA2CPolicy, resolved_policy_defaults
    from sb3_ua2c.registry import resolved_kwargs
    from sb3_ua2c.ua2c import UA2C

    out = _signature_defaults(UA2C, ("self", "policy", "env", "policy_kwargs"))
    rule = ExecutionRule()
    for name in ("entropy_threshold", "target_plan_length", "entropy_quantile", "entropy_growth"):
        if name in out:
            out[name] = getattr(rule, name)
    if "execution_rule" in out:
        out["execution_rule"] = rule.rule
    for option, registry in OPTIONS.items():
        out[f"{option}_kwargs"] = resolved_kwargs(registry, out[option], out[f"{option}_kwargs"])
    names = policy_kwargs_names(UA2CPolicy, UA2C)
    policy = _signature_defaults(UA2CPolicy, ("self",))
    out["policy_kwargs"] = resolved_policy_defaults({k: v for k, v in policy.items() if k in names})
    return copy.deepcopy(out)


__all__ = ["defaults"]
