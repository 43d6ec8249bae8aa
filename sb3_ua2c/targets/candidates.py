"""The paper's bootstrap (Eq. 4 / 8), ``critic_target="candidates"``
(:data:`~sb3_ua2c.targets.CRITIC_TARGETS`): the best of ``n_target_candidates`` chunks that the current actor samples at the next history.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.2 (Eq. 4, 8).
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th

from sb3_ua2c.chunking import bootstrap_value
from sb3_ua2c.targets.base import TargetInputs


class CandidateTarget:
    """
    ``V(h') = max_q min_j Q̄_j(h', â^(q))`` (:func:`~sb3_ua2c.chunking.bootstrap_value`) over
    ``n_target_candidates`` chunks of the current actor, sampled with ``target_flow_steps`` Euler steps
    from torch's global random stream. It has no own arguments and no value network.
    """

    #: fits a value network ``V(h)`` (``actor_extraction="awr"`` reads it)
    fits_value: ClassVar[bool] = False
    #: the value network's arguments the policy must hold (``None``: none)
    value_arch: ClassVar[dict[str, Any] | None] = None

    def value_loss(self, inputs: TargetInputs, data: Any) -> tuple[th.Tensor, dict[str, float]] | None:
        """No value network to fit: ``None``."""
        return None

    def next_value(
        self, inputs: TargetInputs, obs_history: th.Tensor, action_history: th.Tensor
    ) -> th.Tensor:
        """
        :param inputs: the policy and the targets' sampler settings
        :param obs_history: ``(M, ℓ, obs_dim)``
        :param action_history: ``(M, ℓ, action_dim)``
        :return: shape ``(M,)``
        """
        m = obs_history.shape[0]
        policy = inputs.policy
        candidates = policy.sample_chunks(obs_history, action_history, inputs.n_candidates, inputs.flow_steps)
        next_q = policy.critic_target(obs_history.reshape(m, -1), candidates.clamp(-1.0, 1.0))  # (n, M, Q)
        return bootstrap_value(next_q)  # (n, M, Q) -> (M,)


__all__ = ["CandidateTarget"]
