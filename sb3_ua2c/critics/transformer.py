"""The paper's chunk critic (§3.1): ``n_critics`` per-token Transformer critics evaluated as one
ensemble, ``critic_arch="transformer"`` (:data:`~sb3_ua2c.critics.CRITICS`).

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.1.
"""

from __future__ import annotations

import math

import torch as th
from torch import nn

from sb3_ua2c.checks import check_int
from sb3_ua2c.critics.ensemble import EnsembleLinear, EnsembleRMSNorm


def _softmax(x: th.Tensor) -> th.Tensor:
    """Softmax over the last dim; written out because ``torch.softmax`` is several times slower on CPU
    for rows of about ten entries (the attention rows of a chunk critic)."""
    e = (x - x.amax(dim=-1, keepdim=True)).exp()
    return e / e.sum(dim=-1, keepdim=True)


class _EnsembleBlock(nn.Module):
    """Pre-norm Transformer encoder block for ``n`` independent members, input ``(n, B, T, d)``."""

    def __init__(self, n: int, dim: int, n_heads: int, ff_dim: int, activation_fn: type[nn.Module]) -> None:
        super().__init__()
        self.n_heads = n_heads
        self.norm1 = EnsembleRMSNorm(n, dim)
        self.qkv = EnsembleLinear(n, dim, 3 * dim)
        self.out = EnsembleLinear(n, dim, dim)
        self.norm2 = EnsembleRMSNorm(n, dim)
        self.ff1 = EnsembleLinear(n, dim, ff_dim)
        self.act = activation_fn()
        self.ff2 = EnsembleLinear(n, ff_dim, dim)

    def forward(self, x: th.Tensor) -> th.Tensor:
        """
        :param x: tokens, shape ``(n, B, T, d)``
        :return: shape ``(n, B, T, d)``
        """
        n, b, t, d = x.shape
        h = d // self.n_heads
        flat = x.reshape(n, b * t, d)  # (n, B, T, d) -> (n, B*T, d)
        qkv = self.qkv(self.norm1(flat))  # (n, B*T, 3d)
        # explicit attention: for a dozen tokens it is faster on CPU than the fused SDPA kernels
        if self.n_heads == 1:  # no head permutes: (n, B*T, 3d) -> 3 x (n*B, T, d)
            q, k, v = qkv.reshape(n * b, t, 3 * d).split(d, dim=-1)
        else:  # (n, B*T, 3d) -> 3 x (n*B, heads, T, d/heads)
            q, k, v = (
                qkv.reshape(n, b, t, 3, self.n_heads, h)
                .permute(3, 0, 1, 4, 2, 5)
                .reshape(3, n * b, self.n_heads, t, h)
            )
        scores = th.matmul(q, k.transpose(-1, -2)) * (1.0 / math.sqrt(h))  # (n*B, [heads,] T, T)
        att = th.matmul(_softmax(scores), v)
        if self.n_heads == 1:
            att = att.reshape(n, b * t, d)
        else:  # (n*B, heads, T, d/heads) -> (n, B*T, d)
            att = att.reshape(n, b, self.n_heads, t, h).permute(0, 1, 3, 2, 4).reshape(n, b * t, d)
        flat = flat + self.out(att)
        flat = flat + self.ff2(self.act(self.ff1(self.norm2(flat))))
        return flat.reshape(n, b, t, d)


class ChunkCritics(nn.Module):
    """
    Twin (``n_critics``) Transformer chunk critics ``Q_phi_j(o_{t-ℓ+1:t}, a_{t:t+k-1})`` of Eq. 3,
    evaluated in one batched call.

    Token layout (compact): one token for the whole observation history (a linear projection of
    ``ℓ * obs_dim`` numbers) followed by ``k`` action tokens, each with a learned position
    embedding; the value is a learned linear read-out of all ``1 + k`` output tokens, so that every
    action position keeps its own non-linear path (a chunk return is a sum over its steps).

    :param obs_history_dim: ``ℓ * obs_dim``
    :param chunk_size: ``k``
    :param action_dim: action size
    :param n_critics: number of critics (2 for clipped double-Q)
    :param activation_fn: activation class
    :param embed_dim: token width ``d`` (``critic_kwargs["embed_dim"]``, as the next three)
    :param n_layers: number of Transformer blocks
    :param n_heads: attention heads (must divide ``embed_dim``)
    :param ff_dim: hidden width of the feed-forward sublayer
    """

    def __init__(
        self,
        obs_history_dim: int,
        chunk_size: int,
        action_dim: int,
        n_critics: int,
        activation_fn: type[nn.Module],
        embed_dim: int = 32,
        n_layers: int = 1,
        n_heads: int = 1,
        ff_dim: int = 64,
    ) -> None:
        super().__init__()
        for name, value in (("embed_dim", embed_dim), ("n_layers", n_layers), ("n_heads", n_heads), ("ff_dim", ff_dim)):
            check_int(f"critic_kwargs['{name}']", value)
        if embed_dim % n_heads:
            raise ValueError(f"critic_kwargs['n_heads']={n_heads} must divide critic_kwargs['embed_dim']={embed_dim}")
        self.n_critics, self.embed_dim = n_critics, embed_dim
        self.obs_token = EnsembleLinear(n_critics, obs_history_dim, embed_dim)
        self.action_token = EnsembleLinear(n_critics, action_dim, embed_dim)
        self.position = nn.Parameter(th.randn(n_critics, 1, chunk_size + 1, embed_dim) * 0.02)
        self.blocks = nn.ModuleList(
            [_EnsembleBlock(n_critics, embed_dim, n_heads, ff_dim, activation_fn) for _ in range(n_layers)]
        )
        self.norm = EnsembleRMSNorm(n_critics, embed_dim)
        self.head = EnsembleLinear(n_critics, (chunk_size + 1) * embed_dim, 1)

    def forward(self, obs_history: th.Tensor, chunks: th.Tensor) -> th.Tensor:
        """
        :param obs_history: flattened observation histories, shape ``(B, ℓ*obs_dim)``
        :param chunks: ``C`` candidate chunks per history, shape ``(B, C, k, action_dim)``
        :return: Q-values, shape ``(n_critics, B, C)``
        """
        b, c, k, a = chunks.shape
        n, d = self.n_critics, self.embed_dim
        obs_tok = self.obs_token(obs_history)  # (B, ℓ*obs_dim) -> (n, B, d)
        obs_tok = obs_tok.reshape(n, b, 1, 1, d).expand(n, b, c, 1, d)  # shared by the C candidates
        act_tok = self.action_token(chunks.reshape(b * c * k, a)).reshape(n, b, c, k, d)
        x = th.cat([obs_tok, act_tok], dim=3).reshape(n, b * c, k + 1, d) + self.position  # (n, B*C, 1+k, d)
        for block in self.blocks:
            x = block(x)
        x = self.norm(x.reshape(n, b * c * (k + 1), d)).reshape(n, b * c, (k + 1) * d)  # (n, B*C, (1+k)*d)
        return self.head(x).reshape(n, b, c)  # (n, B*C, 1) -> (n, B, C)


__all__ = ["ChunkCritics"]
