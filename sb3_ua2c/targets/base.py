"""The interface of the critics' bootstraps (:data:`~sb3_ua2c.targets.CRITIC_TARGETS`) and what they read of
the model."""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import torch as th


class TargetInputs(NamedTuple):
    """What a target class reads of the model."""

    #: the policy (:class:`~sb3_ua2c.policies.UA2CPolicy`): its ``critic_target``, ``sample_chunks``
    #: and ``value``
    policy: Any
    #: ``n_target_candidates`` (the candidates' bootstrap only)
    n_candidates: int
    #: ``target_flow_steps`` (the candidates' bootstrap only)
    flow_steps: int


class CriticTarget(Protocol):
    """The interface of a class of :data:`~sb3_ua2c.targets.CRITIC_TARGETS`, built as
    ``cls(**critic_target_kwargs)``."""

    #: fits a value network (``actor_extraction="awr"`` reads it)
    fits_value: bool
    #: the arguments of the value network :class:`~sb3_ua2c.targets.in_sample.ChunkValue` the policy must
    #: hold (``None``: none)
    value_arch: dict[str, Any] | None

    def value_loss(self, inputs: TargetInputs, data: Any) -> tuple[th.Tensor, dict[str, float]] | None:
        """The loss of the value network on a batch and its logged floats (``None``: nothing to fit)."""

    def next_value(
        self, inputs: TargetInputs, obs_history: th.Tensor, action_history: th.Tensor
    ) -> th.Tensor:
        """``(M, ℓ, obs_dim), (M, ℓ, action_dim) -> V(h)``, shape ``(M,)`` (called without gradient)."""


__all__ = ["CriticTarget", "TargetInputs"]
