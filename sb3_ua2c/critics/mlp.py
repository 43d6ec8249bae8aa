"""Q-chunking's critic (Li et al., 2025): ``n_critics`` MLPs over the flattened (history, chunk) input,
evaluated as one ensemble, ``critic_arch="mlp"`` (:data:`~sb3_ua2c.critics.CRITICS`).

It is the worked example of docs/algorithm.md, "Adding a critic or an actor": this module and its
line in :data:`~sb3_ua2c.critics.CRITICS` are all a critic takes.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch as th
from torch import nn

from sb3_ua2c.checks import check_bool, check_net_arch
from sb3_ua2c.critics.ensemble import EnsembleLayerNorm, EnsembleLinear


class MLPChunkCritics(nn.Module):
    """
    Twin (``n_critics``) MLP chunk critics ``Q_phi_j(o_{t-ℓ+1:t}, a_{t:t+k-1})`` over the flattened
    (observation history, chunk) input, as Q-chunking's critic (Li et al., 2025), evaluated in one
    batched call: each layer holds the members' weights stacked, ``(n, in, out)``.

    Each hidden layer is linear, then (optionally) a layer norm, then the activation; the value is a
    linear read-out. The first layer is split into a history part, computed once per history, and a
    chunk part, so that the ``C`` candidates of a history share the history's features. Same call as
    :class:`~sb3_ua2c.critics.transformer.ChunkCritics`.

    :param obs_history_dim: ``ℓ * obs_dim``
    :param chunk_size: ``k``
    :param action_dim: action size
    :param n_critics: number of critics (2 for clipped double-Q)
    :param activation_fn: activation class
    :param net_arch: hidden layer sizes, at least one (``critic_kwargs["net_arch"]``; SAC's by default)
    :param layer_norm: a layer norm before each hidden activation (as RLPD's and Q-chunking's critics)
    """

    def __init__(
        self,
        obs_history_dim: int,
        chunk_size: int,
        action_dim: int,
        n_critics: int,
        activation_fn: type[nn.Module],
        net_arch: Sequence[int] = (256, 256),
        layer_norm: bool = True,
    ) -> None:
        super().__init__()
        check_net_arch("critic_kwargs['net_arch']", net_arch)
        check_bool("critic_kwargs['layer_norm']", layer_norm)
        self.n_critics = n_critics
        self.obs_layer = EnsembleLinear(n_critics, obs_history_dim, net_arch[0])
        self.chunk_layer = EnsembleLinear(n_critics, chunk_size * action_dim, net_arch[0], bias=False)
        self.hidden = nn.ModuleList(
            [EnsembleLinear(n_critics, n_in, n_out) for n_in, n_out in zip(net_arch[:-1], net_arch[1:], strict=True)]
        )
        norms = [EnsembleLayerNorm(n_critics, width) if layer_norm else nn.Identity() for width in net_arch]
        self.norms = nn.ModuleList(norms)
        self.act = activation_fn()
        self.head = EnsembleLinear(n_critics, net_arch[-1], 1)

    def forward(self, obs_history: th.Tensor, chunks: th.Tensor) -> th.Tensor:
        """
        :param obs_history: flattened observation histories, shape ``(B, ℓ*obs_dim)``
        :param chunks: ``C`` candidate chunks per history, shape ``(B, C, k, action_dim)``
        :return: Q-values, shape ``(n_critics, B, C)``
        """
        b, c = chunks.shape[:2]
        n = self.n_critics
        obs = self.obs_layer(obs_history)  # (n, B, h): once per history
        act = self.chunk_layer(chunks.reshape(b * c, -1))  # (B*C, k*a) -> (n, B*C, h)
        x = (act.reshape(n, b, c, -1) + obs.unsqueeze(2)).reshape(n, b * c, -1)  # (n, B*C, h)
        x = self.act(self.norms[0](x))
        for layer, norm in zip(self.hidden, self.norms[1:], strict=True):
            x = self.act(norm(layer(x)))
        return self.head(x).reshape(n, b, c)  # (n, B*C, 1) -> (n, B, C)


__all__ = ["MLPChunkCritics"]
