"""Loading checkpoints of earlier layouts.

Before release 0.1.0 the execution rule was five separate arguments (``execution_rule``,
``entropy_threshold``, ``target_plan_length``, ``entropy_quantile``, ``entropy_growth``), saved one by
one among a model's attributes and a policy's constructor arguments. They are now one
:class:`~sb3_ua2c.config.ExecutionRule`; :func:`legacy_execution_rule` turns the old entries into it, so
such checkpoints load (and act) as before. The same names given to ``UA2C.load`` override the saved
rule field by field, as SB3's ``load(path, **kwargs)`` overrides attributes.

The critics' own arguments were flat policy arguments too (``critic_embed_dim``, ``critic_net_arch``,
...); they are now ``critic_kwargs`` of the ``critic_arch``'s class (:mod:`sb3_ua2c.critics`).
:func:`legacy_critic_kwargs` moves the saved flat entries of a checkpoint into it; given by a user,
they raise a ``ValueError`` (:func:`reject_legacy_policy_kwargs`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from sb3_ua2c.config import ExecutionRule

#: the saved name of each field of :class:`~sb3_ua2c.config.ExecutionRule` in the earlier layout
LEGACY_RULE_NAMES = {
    "execution_rule": "rule",
    "entropy_threshold": "entropy_threshold",
    "target_plan_length": "target_plan_length",
    "entropy_quantile": "entropy_quantile",
    "entropy_growth": "entropy_growth",
}

#: the flat policy argument of the earlier layout -> ``(critic_arch it applied to, key of critic_kwargs)``
LEGACY_CRITIC_NAMES = {
    "critic_embed_dim": ("transformer", "embed_dim"),
    "critic_n_layers": ("transformer", "n_layers"),
    "critic_n_heads": ("transformer", "n_heads"),
    "critic_ff_dim": ("transformer", "ff_dim"),
    "critic_net_arch": ("mlp", "net_arch"),
    "critic_layer_norm": ("mlp", "layer_norm"),
}


def legacy_execution_rule(saved: dict[str, Any], execution: ExecutionRule | None) -> ExecutionRule | None:
    """
    Remove the execution-rule entries of the earlier layout from ``saved`` (a model's attributes or a
    policy's constructor arguments) and apply them to ``execution``.

    :param saved: the saved entries; modified in place (the legacy names are popped)
    :param execution: the saved rule of the current layout, or ``None`` (an earlier checkpoint: the
        defaults of :class:`~sb3_ua2c.config.ExecutionRule` stand for the entries it lacks)
    :return: ``execution`` with the legacy entries applied (a new, checked rule), or ``execution`` itself
        when ``saved`` holds none of them
    """
    fields = {field: saved.pop(name) for name, field in LEGACY_RULE_NAMES.items() if name in saved}
    if not fields:
        return execution
    return dataclasses.replace(ExecutionRule() if execution is None else execution, **fields)


def legacy_critic_kwargs(saved: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """
    A checkpoint's policy arguments with the critics' flat entries of the earlier layout moved into
    ``critic_kwargs``: those of the saved ``critic_arch`` (default ``"transformer"``, the only one of the
    earliest checkpoints) become its keys, the others are dropped (they did not act on that critic);
    a ``None`` entry (the earlier "default") is left out, so the class's default stands.

    :param saved: a policy's constructor arguments, or a model's ``policy_kwargs`` (``None``: none)
    :return: a new dict (``saved`` itself when it holds no flat entry)
    """
    if saved is None or not any(name in saved for name in LEGACY_CRITIC_NAMES):
        return None if saved is None else dict(saved)
    out = {k: v for k, v in saved.items() if k not in LEGACY_CRITIC_NAMES}
    arch = out.get("critic_arch", "transformer")  # the earliest checkpoints saved none: the Transformer
    own = {key: saved[name] for name, (applies_to, key) in LEGACY_CRITIC_NAMES.items()
           if name in saved and applies_to == arch and saved[name] is not None}
    out["critic_kwargs"] = {**own, **(out.get("critic_kwargs") or {})}
    return out


def reject_legacy_policy_kwargs(policy_kwargs: Mapping[str, Any] | None) -> None:
    """
    Raise ``ValueError`` naming a flat critic argument of the earlier layout given in ``policy_kwargs``
    (a new model's: a checkpoint's are translated by :func:`legacy_critic_kwargs`).

    :param policy_kwargs: the policy's arguments
    """
    for name, (arch, key) in LEGACY_CRITIC_NAMES.items():
        if name in (policy_kwargs or {}):
            raise ValueError(
                f"policy_kwargs[{name!r}] is no longer an argument: use critic_kwargs={{{key!r}: ...}} "
                f"(the arguments of critic_arch={arch!r}, see sb3_ua2c.critics)"
            )


__all__ = [
    "LEGACY_CRITIC_NAMES",
    "LEGACY_RULE_NAMES",
    "legacy_critic_kwargs",
    "legacy_execution_rule",
    "reject_legacy_policy_kwargs",
]
