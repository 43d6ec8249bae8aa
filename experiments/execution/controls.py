"""What an execution rule is compared against: the checkpoint under another rule (:func:`apply_rule`), and controls
that keep the executed lengths but drop the uncertainty (:class:`RandomCut`, :class:`FixedCut`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch as th

from sb3_ua2c import UA2C
from sb3_ua2c.config import ExecutionRule

#: The rules a screen compares, by arm name: UA2C's execution-rule arguments (``execution_rule`` and its parameters).
RULES: dict[str, dict[str, Any]] = {
    "fixed": {"entropy_threshold": math.inf},
    "delta0": {"entropy_threshold": 0.0},  # same as default: the rule is δ = 0 by name
    "quantile0.5": {"execution_rule": "quantile", "entropy_quantile": 0.5},
    "quantile0.75": {"execution_rule": "quantile", "entropy_quantile": 0.75},
    "quantile0.9": {"execution_rule": "quantile", "entropy_quantile": 0.9},
    "growth0.25": {"execution_rule": "growth", "entropy_growth": 0.25},
    "growth0.5": {"execution_rule": "growth", "entropy_growth": 0.5},
    "growth1": {"execution_rule": "growth", "entropy_growth": 1.0},
}


class RandomCut:
    """``L_t`` drawn from the ``(k,)`` probabilities ``shares``, whatever the entropies (one generator of ``seed``)."""

    def __init__(self, shares: Sequence[float], seed: int) -> None:
        p = np.asarray(shares, dtype=np.float64)
        if p.ndim != 1 or p.size == 0 or np.any(p < 0) or not math.isclose(p.sum(), 1.0, abs_tol=1e-6):
            raise ValueError(f"shares must be probabilities of L_t = 1..k, got {list(shares)}")
        self.probabilities = th.as_tensor(p / p.sum(), dtype=th.float64)
        self.generator = th.Generator().manual_seed(seed)

    def __call__(self, entropy: th.Tensor) -> th.Tensor:
        m = entropy.shape[0]
        draws = th.multinomial(self.probabilities, m, replacement=True, generator=self.generator)  # (m,)
        return (draws + 1).to(device=entropy.device)


class FixedCut:
    """``L_t = k'`` at every replanning: fixed chunks of ``k' <= k`` actions from a ``k``-action plan."""

    def __init__(self, length: int, chunk_size: int) -> None:
        if not 1 <= length <= chunk_size:
            raise ValueError(f"length must be in [1, {chunk_size}], got {length}")
        self.length = int(length)

    def __call__(self, entropy: th.Tensor) -> th.Tensor:
        return th.full(entropy.shape[:1], self.length, dtype=th.long, device=entropy.device)


def apply_rule(model: UA2C, rule: Mapping[str, Any], calibration_episodes: Sequence[Any] | None = None,
               n_histories: int = 1024) -> None:
    """Act under ``rule`` (as in :data:`RULES`), a quantile rule calibrated on ``calibration_episodes``."""
    model.policy.__dict__.pop("plan_lengths", None)  # drop a control
    fields = dict(rule)
    model.set_execution_rule(ExecutionRule(fields.pop("execution_rule", "threshold"), **fields))
    if model.policy.needs_calibration:
        if not calibration_episodes:
            raise ValueError("the quantile rule needs calibration episodes")
        model.replay_buffer.reset()
        model.add_offline_episodes(calibration_episodes)
        model.calibrate_execution(n_histories=n_histories)


def apply_control(model: UA2C, control: RandomCut | FixedCut) -> None:
    """Act with the lengths of ``control`` (the selection of the executed chunk is unchanged)."""
    model.policy.plan_lengths = control  # an instance attribute shadows UA2CPolicy.plan_lengths
