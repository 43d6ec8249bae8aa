"""UA2C's validated configuration: the chunking hyperparameters (:class:`UA2CConfig`) and the checks of
the spaces and ``policy_kwargs`` that :class:`~sb3_ua2c.ua2c.UA2C` accepts."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_ua2c.buffers import check_online_targets
from sb3_ua2c.checks import check_bool, check_int
from sb3_ua2c.chunking import check_entropy_threshold
from sb3_ua2c.policies import UA2CPolicy


@dataclass(frozen=True)
class UA2CConfig:
    """
    Chunking hyperparameters of UA2C (validated; a bad value raises ``ValueError`` naming it; numbers are
    stored as ``float``).

    :param chunk_size: chunk length ``k`` (1 = one-step baseline)
    :param history_len: history length ``ℓ``
    :param flow_steps: Euler steps ``N`` when acting
    :param target_flow_steps: Euler steps for the target candidates of Eq. 4 / 8
    :param n_candidates: chunks ``S`` sampled per replanning (Eq. 7)
    :param n_target_candidates: candidates ``Q`` for the target max (Eq. 4 / 8)
    :param entropy_threshold: ``delta`` of Eq. 7 (``inf`` = the whole chunk), or ``"auto"`` (δ set from
        recent replannings for a mean ``L_t`` of ``target_plan_length``)
    :param target_plan_length: with ``entropy_threshold="auto"`` only: the target mean ``L_t`` in ``[1, k]``
        (``None`` = ``(k + 1) / 2``)
    :param q_weight: ``lambda`` of Eq. 2
    :param smooth_weight: ``mu`` of the in-chunk smoothness term added to Eq. 2 (0 = the paper)
    :param discrete_entropy: ``H_u`` of Eq. 7 includes the categorical action dims
    :param commit_discrete: ``L_t`` extends through the first switch of a categorical action in the
        selected chunk (not in the paper)
    :param offline_ratio: fraction of each batch drawn from offline episodes when both parts hold data
    :param online_targets: ``"prefix"`` (Eq. 8), ``"window"`` (Eq. 4 on executed actions) or
        ``"auto"`` (Eq. 8 with offline data, windows without), see
        :class:`~sb3_ua2c.buffers.ChunkReplayBuffer`
    """

    chunk_size: int = 5
    history_len: int = 4
    flow_steps: int = 10
    target_flow_steps: int = 2
    n_candidates: int = 32
    n_target_candidates: int = 2
    entropy_threshold: float | str = 0.0
    target_plan_length: float | None = None
    q_weight: float = 1.0
    smooth_weight: float = 0.0
    discrete_entropy: bool = True
    commit_discrete: bool = False
    offline_ratio: float = 0.5
    online_targets: str = "auto"

    def __post_init__(self) -> None:
        for name in (
            "chunk_size",
            "history_len",
            "flow_steps",
            "target_flow_steps",
            "n_candidates",
            "n_target_candidates",
        ):
            check_int(name, getattr(self, name))
        for name in ("q_weight", "smooth_weight", "offline_ratio"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number) or math.isnan(value):
                raise ValueError(f"{name} must be a number, got {value!r}")
            object.__setattr__(self, name, float(value))
        delta, target = check_entropy_threshold(self.entropy_threshold, self.target_plan_length, self.chunk_size)
        object.__setattr__(self, "entropy_threshold", delta)
        object.__setattr__(self, "target_plan_length", target)
        for name in ("q_weight", "smooth_weight"):
            if not 0.0 <= getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.offline_ratio <= 1.0:
            raise ValueError(f"offline_ratio must be in [0, 1], got {self.offline_ratio!r}")
        check_online_targets(self.online_targets)
        for name in ("discrete_entropy", "commit_discrete"):
            check_bool(name, getattr(self, name))
            object.__setattr__(self, name, bool(getattr(self, name)))


_POLICY_KWARGS_SET_BY_UA2C = {
    "chunk_size",
    "history_len",
    "flow_steps",
    "n_candidates",
    "entropy_threshold",
    "target_plan_length",
    "discrete_dims",
    "discrete_entropy",
    "commit_discrete",
}


def check_spaces(observation_space: spaces.Space | None, action_space: spaces.Space | None) -> None:
    if action_space is not None and not isinstance(action_space, spaces.Box):
        raise ValueError(f"UA2C supports Box action spaces only, got {type(action_space).__name__}")
    if observation_space is not None and not isinstance(observation_space, spaces.Box):
        raise ValueError(f"UA2C supports Box observation spaces only, got {type(observation_space).__name__}")
    if isinstance(action_space, spaces.Box) and not (
        np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))
    ):
        raise ValueError("UA2C needs a bounded Box action space (finite low and high)")


def check_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> None:
    if not policy_kwargs:
        return
    allowed = set(inspect.signature(UA2CPolicy.__init__).parameters) - {
        "self",
        "observation_space",
        "action_space",
        "lr_schedule",
    }
    for key in policy_kwargs:
        if key in _POLICY_KWARGS_SET_BY_UA2C:
            raise ValueError(
                f"policy_kwargs[{key!r}] is set by UA2C's own argument; pass it to UA2C(...) instead"
            )
        if key not in allowed - _POLICY_KWARGS_SET_BY_UA2C:
            raise ValueError(
                f"unknown policy_kwargs key {key!r}; allowed: {sorted(allowed - _POLICY_KWARGS_SET_BY_UA2C)}"
            )


__all__ = ["UA2CConfig", "check_policy_kwargs", "check_spaces"]
