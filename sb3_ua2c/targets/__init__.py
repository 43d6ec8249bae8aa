"""The bootstrap of the critics' targets (Eq. 4 / 8), by name: UA2C's ``critic_target`` picks a class of
:data:`CRITIC_TARGETS` and ``critic_target_kwargs`` holds that class's own arguments, whose defaults are
in its signature (:mod:`sb3_ua2c.registry`). ``UA2C`` asks a target class for :class:`CriticTarget`
only: the value of the next history in ``y = Σ_{u<L} γ^u r + m γ^L V(h_{t+L})``
(:func:`~sb3_ua2c.chunking.chunk_target`), and the loss of the value network it needs, if any.

A new bootstrap is one module with one class and one line in :data:`CRITIC_TARGETS`
(docs/algorithm.md, "Adding a critic or an actor").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import torch as th

from sb3_ua2c.targets.candidates import CandidateTarget
from sb3_ua2c.targets.in_sample import ChunkValue, InSampleTarget

if TYPE_CHECKING:
    from sb3_ua2c.policies import UA2CPolicy


class TargetInputs(NamedTuple):
    """What a target class reads of the model."""

    #: the policy: its ``critic_target``, ``sample_chunks`` and ``value`` (``None`` without one)
    policy: UA2CPolicy
    #: ``n_target_candidates`` (the candidates' bootstrap only)
    n_candidates: int
    #: ``target_flow_steps`` (the candidates' bootstrap only)
    flow_steps: int


class CriticTarget(Protocol):
    """The interface of a class of :data:`CRITIC_TARGETS`, built as ``cls(**critic_target_kwargs)``."""

    #: fits a value network (``actor_extraction="awr"`` reads it)
    fits_value: bool
    #: the arguments of the value network :class:`ChunkValue` the policy must hold (``None``: none)
    value_arch: dict[str, Any] | None

    def value_loss(self, inputs: TargetInputs, data: Any) -> tuple[th.Tensor, dict[str, float]] | None:
        """The loss of the value network on a batch and its logged floats (``None``: nothing to fit)."""

    def next_value(self, inputs: TargetInputs, obs_history: th.Tensor, action_history: th.Tensor) -> th.Tensor:
        """``(M, ℓ, obs_dim), (M, ℓ, action_dim) -> V(h)``, shape ``(M,)`` (called without gradient)."""


#: the bootstraps by ``critic_target``: the paper's max over actor candidates, or IQL's in-sample value
CRITIC_TARGETS: dict[str, type] = {
    "candidates": CandidateTarget,
    "in_sample": InSampleTarget,
}


__all__ = ["CRITIC_TARGETS", "CandidateTarget", "ChunkValue", "CriticTarget", "InSampleTarget", "TargetInputs"]
