"""Loading checkpoints of earlier layouts.

Before release 0.1.0 the execution rule was five separate arguments (``execution_rule``,
``entropy_threshold``, ``target_plan_length``, ``entropy_quantile``, ``entropy_growth``), saved one by
one among a model's attributes and a policy's constructor arguments. They are now one
:class:`~sb3_ua2c.config.ExecutionRule`; :func:`legacy_execution_rule` turns the old entries into it, so
such checkpoints load (and act) as before. The same names given to ``UA2C.load`` override the saved
rule field by field, as SB3's ``load(path, **kwargs)`` overrides attributes.
"""

from __future__ import annotations

import dataclasses
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


__all__ = ["LEGACY_RULE_NAMES", "legacy_execution_rule"]
