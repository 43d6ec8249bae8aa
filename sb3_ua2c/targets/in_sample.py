"""The in-sample chunk value (not in the UA2C paper), ``critic_target="in_sample"``
(:data:`~sb3_ua2c.targets.CRITIC_TARGETS`): IQL's expectile value (Kostrikov et al., ICLR 2022), as
IFQL / SHARSA use it for flow policies (Park et al., 2025), over chunks as Q-chunking's backup (Li et
al., 2025). No target queries a chunk the data lacks, and no actor candidate is sampled.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import torch as th
from torch import nn

from sb3_ua2c.checks import check_bool, check_net_arch, check_number
from sb3_ua2c.chunking import pessimistic_q
from sb3_ua2c.in_sample_maths import expectile_loss
from sb3_ua2c.targets.base import TargetInputs


class ChunkValue(nn.Module):
    """
    The value ``V(h_t)`` of an observation history, an MLP over the flattened history (as the critics
    see it, without past actions): each hidden layer linear, then (optionally) a layer norm, then the
    activation; a linear read-out. The policy holds it as ``value`` (state-dict prefix ``value.*``).

    :param obs_history_dim: ``ℓ * obs_dim``
    :param activation_fn: activation class (the policy's)
    :param net_arch: hidden sizes (declared by :class:`InSampleTarget`)
    :param layer_norm: a layer norm before each hidden activation
    """

    def __init__(
        self, obs_history_dim: int, activation_fn: type[nn.Module], net_arch: Sequence[int], layer_norm: bool
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for n_in, n_out in zip([obs_history_dim, *net_arch[:-1]], net_arch, strict=True):
            layers += [nn.Linear(n_in, int(n_out)), nn.LayerNorm(int(n_out)) if layer_norm else nn.Identity(),
                       activation_fn()]
        layers.append(nn.Linear(int(net_arch[-1]), 1))
        self.net = nn.Sequential(*layers)

    def forward(self, obs_history: th.Tensor) -> th.Tensor:
        """
        :param obs_history: flattened observation histories, ``(B, ℓ*obs_dim)``
        :return: ``V(h)``, shape ``(B,)``
        """
        return self.net(obs_history).squeeze(-1)  # (B, 1) -> (B,)


class InSampleTarget:
    """
    The in-sample bootstrap: ``V(h_t)`` is fitted by expectile regression
    (:func:`~sb3_ua2c.in_sample_maths.expectile_loss`, IQL's Eq. 5) to ``min_j Q̄_j(h_t, a_{t:t+k})`` of the
    data's own chunk (the target critics, no gradient), and the critics regress on
    ``Σ_{u<L} γ^u r_{t+u} + m γ^L V(h_{t+L})`` (:func:`~sb3_ua2c.chunking.chunk_target` with ``V`` in place
    of the candidates' max; ``L`` and ``m`` as in Eq. 4 / 8).

    :param expectile: ``tau`` in ``(0, 1)`` (d3rlpy's IQL default; 0.5 = the mean, a SARSA value of the
        data's chunks; ``-> 1``: their in-sample maximum)
    :param net_arch: hidden sizes of ``V`` (:class:`ChunkValue`)
    :param layer_norm: a layer norm before each hidden activation of ``V``
    """

    #: fits a value network ``V(h)`` (``actor_extraction="awr"`` reads it)
    fits_value: ClassVar[bool] = True

    def __init__(
        self, expectile: float = 0.7, net_arch: Sequence[int] = (256, 256), layer_norm: bool = True
    ) -> None:
        check_number("critic_target_kwargs['expectile']", expectile, 0.0, 1.0, open_low=True, open_high=True)
        check_net_arch("critic_target_kwargs['net_arch']", net_arch)
        check_bool("critic_target_kwargs['layer_norm']", layer_norm)
        self.expectile = float(expectile)
        self.net_arch = [int(h) for h in net_arch]
        self.layer_norm = bool(layer_norm)

    @property
    def value_arch(self) -> dict[str, Any]:
        """The arguments of the policy's :class:`ChunkValue` (``UA2CPolicy(value_arch=...)``)."""
        return {"net_arch": list(self.net_arch), "layer_norm": self.layer_norm}

    def value_loss(self, inputs: TargetInputs, data: Any) -> tuple[th.Tensor, dict[str, float]]:
        """
        The expectile loss of ``V`` on the batch: ``(B, ℓ, obs_dim)`` histories and ``(B, k, A)`` chunks.

        :param inputs: the policy (its ``value`` and ``critic_target``)
        :param data: the batch (``observation_history``, ``chunks``)
        :return: the loss and the logged ``value_loss``, ``v_mean``
        """
        obs_flat = data.observation_history.flatten(1)  # (B, ℓ, obs_dim) -> (B, ℓ*obs_dim)
        with th.no_grad():
            q = pessimistic_q(inputs.policy.critic_target(obs_flat, data.chunks.unsqueeze(1)))  # (n, B, 1) -> (B, 1)
            q = q[:, 0]  # (B, 1) -> (B,)
        v = inputs.policy.value(obs_flat)  # (B,)
        loss = expectile_loss(q, v, self.expectile)
        return loss, {"value_loss": loss.item(), "v_mean": v.mean().item()}

    def next_value(
        self, inputs: TargetInputs, obs_history: th.Tensor, action_history: th.Tensor
    ) -> th.Tensor:
        """
        :param inputs: the policy (its ``value``)
        :param obs_history: ``(M, ℓ, obs_dim)``
        :param action_history: ``(M, ℓ, action_dim)`` (not read: ``V`` sees the observations only)
        :return: ``V(h)``, shape ``(M,)``
        """
        return inputs.policy.value(obs_history.reshape(obs_history.shape[0], -1))


__all__ = ["ChunkValue", "InSampleTarget"]
