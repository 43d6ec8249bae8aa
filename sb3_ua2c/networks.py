"""Networks of UA2C: the flow-matching chunk actor (the velocity field of Eq. 2) and the twin chunk
critics of Eq. 3, evaluated as one ensemble: the paper's Transformer critic (:class:`ChunkCritics`) or
an MLP over the flattened (history, chunk) input as Q-chunking uses (:class:`MLPChunkCritics`).

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ua2c.flow import euler_sample, euler_times


def _trunk(net_arch: list[int], out_dim: int, activation_fn: type[nn.Module]) -> nn.Sequential:
    """The MLP after a first layer of ``net_arch[0]`` units: activation, the other hidden layers, and
    the output layer of ``out_dim`` units (the actors' common tail)."""
    layers: list[nn.Module] = [activation_fn()]
    for n_in, n_out in zip(net_arch[:-1], net_arch[1:], strict=True):
        layers += [nn.Linear(n_in, n_out), activation_fn()]
    layers.append(nn.Linear(net_arch[-1], out_dim))
    return nn.Sequential(*layers)


class VelocityField(nn.Module):
    """
    Conditional velocity field ``v_theta(x_tau, tau | h_t)`` over chunks (Eq. 2), an MLP.

    The first layer is split into a history part, computed once per history, and a chunk/time part,
    so that S candidates x N Euler steps reuse the history features.

    :param history_dim: size of the flattened history ``(o_{t-ℓ+1:t}, a_{t-ℓ:t-1})``
    :param chunk_size: ``k``
    :param action_dim: action size
    :param net_arch: hidden layer sizes (at least one)
    :param activation_fn: activation class

    The sizes and the activation have no defaults here: :class:`~sb3_ua2c.policies.UA2CPolicy` declares them.
    """

    def __init__(
        self,
        history_dim: int,
        chunk_size: int,
        action_dim: int,
        net_arch: list[int],
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        if len(net_arch) == 0:
            raise ValueError("net_arch must have at least one hidden layer for the velocity field")
        self.chunk_size, self.action_dim = chunk_size, action_dim
        chunk_dim = chunk_size * action_dim
        self.history_layer = nn.Linear(history_dim, net_arch[0])
        self.chunk_layer = nn.Linear(chunk_dim, net_arch[0], bias=False)
        self.time_weight = nn.Parameter(th.empty(net_arch[0]).uniform_(-1.0, 1.0))
        self.trunk = _trunk(net_arch, chunk_dim, activation_fn)

    def condition(self, history: th.Tensor) -> th.Tensor:
        """
        :param history: flattened histories, shape ``(batch, history_dim)``
        :return: first-layer history features, shape ``(batch, hidden)``
        """
        return self.history_layer(history)

    def time_condition(self, tau: th.Tensor, cond: th.Tensor, n_extra: int = 0) -> th.Tensor:
        """
        History and time part of the first layer, ``W_h h + b + w_tau tau``.

        :param tau: flow times, shape ``(batch,)`` or ``()`` (shared), or ``(N, 1)`` for N Euler steps
        :param cond: history features from :meth:`condition`, shape ``(batch, hidden)``
        :param n_extra: candidate dims of the chunks to broadcast over
        :return: shape ``(*tau_rows, batch, *[1] * n_extra, hidden)``: ``(batch, ..., hidden)`` for a
            ``(batch,)`` or scalar ``tau``, ``(N, batch, ..., hidden)`` for ``(N, 1)``
        """
        time = tau.to(cond.dtype).unsqueeze(-1) * self.time_weight  # (..., 1 or batch, hidden)
        first = cond + time  # (batch, hidden) or (N, batch, hidden)
        return first.reshape(*first.shape[:-1], *([1] * n_extra), first.shape[-1])

    def flat_velocity(self, x_flat: th.Tensor, first: th.Tensor) -> th.Tensor:
        """
        Velocity of flattened chunks given the first layer's history/time part.

        :param x_flat: chunks, shape ``(batch, *extra, k * action_dim)``
        :param first: from :meth:`time_condition`, broadcastable to ``(batch, *extra, hidden)``
        :return: velocities, shape ``(batch, *extra, k * action_dim)``
        """
        return self.trunk(self.chunk_layer(x_flat) + first)

    def forward(self, x: th.Tensor, tau: th.Tensor, cond: th.Tensor) -> th.Tensor:
        """
        :param x: chunks, shape ``(batch, *extra, k, action_dim)``
        :param tau: flow times, shape ``(batch,)`` or a scalar tensor (shared by all chunks)
        :param cond: history features from :meth:`condition`, shape ``(batch, hidden)``
        :return: velocities, same shape as ``x``
        """
        # the first layer is W_x x + w_tau tau + W_h h (+ b): the history/time part once per history
        first = self.time_condition(tau.reshape(-1), cond, x.ndim - 3)  # (batch, *[1] * extra, hidden)
        return self.flat_velocity(x.flatten(-2), first).reshape(x.shape)

    def sample(self, x0: th.Tensor, cond: th.Tensor, n_steps: int) -> th.Tensor:
        """
        Euler integration (:func:`~sb3_ua2c.flow.euler_sample`) of the velocity field from ``x0``,
        with the history/time part of the first layer computed once for all ``N`` steps.

        :param x0: noise, shape ``(batch, *extra, k, action_dim)``
        :param cond: history features from :meth:`condition`, shape ``(batch, hidden)``
        :param n_steps: Euler steps ``N``
        :return: ``x1`` (not clipped), same shape as ``x0``
        """
        taus = euler_times(n_steps, x0.dtype, x0.device)
        first = self.time_condition(taus.unsqueeze(-1), cond, x0.ndim - 3)  # (N, batch, *[1]*extra, hidden)
        return euler_sample(self.flat_velocity, x0.flatten(-2), n_steps, first).reshape(x0.shape)


class OneStepActor(nn.Module):
    """
    QC-FQL's one-step policy ``mu(h, z)`` (Q-chunking, Li et al., 2025; FQL, Park et al., 2025): an MLP
    from a history and a noise chunk ``z`` to a chunk in one call, distilled from the flow and trained
    against Q (:func:`~sb3_ua2c.flow.one_step_actor_loss`). As in :class:`VelocityField`, the first layer
    is split into a history part, computed once per history, and a noise part, so that S candidates
    reuse the history features.

    :param history_dim: size of the flattened history (the velocity field's input)
    :param chunk_size: ``k``
    :param action_dim: action size
    :param net_arch: hidden layer sizes (at least one; the velocity field's)
    :param activation_fn: activation class
    """

    def __init__(
        self,
        history_dim: int,
        chunk_size: int,
        action_dim: int,
        net_arch: list[int],
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        chunk_dim = chunk_size * action_dim
        self.history_layer = nn.Linear(history_dim, net_arch[0])
        self.noise_layer = nn.Linear(chunk_dim, net_arch[0], bias=False)
        self.trunk = _trunk(net_arch, chunk_dim, activation_fn)

    def forward(self, history: th.Tensor, z: th.Tensor) -> th.Tensor:
        """
        :param history: flattened histories, shape ``(batch, history_dim)``
        :param z: noise chunks, shape ``(batch, *extra, k, action_dim)``
        :return: chunks (not clipped), same shape as ``z``
        """
        first = self.history_layer(history)  # (batch, hidden)
        first = first.reshape(first.shape[0], *([1] * (z.ndim - 3)), first.shape[-1])  # (batch, *[1]*extra, hidden)
        return self.trunk(self.noise_layer(z.flatten(-2)) + first).reshape(z.shape)


def _softmax(x: th.Tensor) -> th.Tensor:
    """Softmax over the last dim; written out because ``torch.softmax`` is several times slower on CPU
    for rows of about ten entries (the attention rows of a chunk critic)."""
    e = (x - x.amax(dim=-1, keepdim=True)).exp()
    return e / e.sum(dim=-1, keepdim=True)


class _EnsembleLinear(nn.Module):
    """``n`` independent linear layers applied in one batched matmul: ``(n, M, in) -> (n, M, out)``.

    Initialised as ``nn.Linear`` (uniform in ``±1/sqrt(in)``); ``bias=False`` leaves the bias out.
    """

    def __init__(self, n: int, in_features: int, out_features: int, bias: bool = True) -> None:
        super().__init__()
        bound = 1.0 / math.sqrt(in_features)
        self.weight = nn.Parameter(th.empty(n, in_features, out_features).uniform_(-bound, bound))
        self.bias = nn.Parameter(th.empty(n, 1, out_features).uniform_(-bound, bound)) if bias else None

    def forward(self, x: th.Tensor) -> th.Tensor:
        if x.ndim == 2:  # shared input (M, in) for all members: one (M, in) x (in, n*out) matmul
            n, n_in, n_out = self.weight.shape
            stacked = self.weight.permute(1, 0, 2).reshape(n_in, n * n_out)  # (in, n*out)
            out = th.mm(x, stacked).reshape(-1, n, n_out).transpose(0, 1)  # (n, M, out)
            return out if self.bias is None else out + self.bias
        if self.bias is None:
            return th.bmm(x, self.weight)
        return th.baddbmm(self.bias, x, self.weight)


class _EnsembleLayerNorm(nn.Module):
    """Layer norm with a per-member gain and bias, input ``(n, M, d)``."""

    def __init__(self, n: int, dim: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.weight = nn.Parameter(th.ones(n, 1, dim))
        self.bias = nn.Parameter(th.zeros(n, 1, dim))
        self.dim, self.eps = dim, eps

    def forward(self, x: th.Tensor) -> th.Tensor:
        # one fused layer norm with its own gain and bias per member: on CPU about 1.7x faster (forward and
        # backward, (2, 512, 256)) than one norm over all members followed by a broadcast gain and bias
        return th.stack([F.layer_norm(x[i], (self.dim,), self.weight[i, 0], self.bias[i, 0], self.eps)
                         for i in range(x.shape[0])])  # (n, M, d)


class _EnsembleRMSNorm(nn.Module):
    """RMS norm (Zhang & Sennrich, 2019) with a per-member gain, input ``(n, M, d)``.

    ``x / sqrt(mean(x^2) + eps) * g``: on CPU it is several times faster than a layer norm over
    rows of a few dozen numbers, which dominate the critics' cost (B * Q target sequences).
    """

    def __init__(self, n: int, dim: int, eps: float = 1e-6) -> None:
        super().__init__()
        self.weight = nn.Parameter(th.ones(n, 1, dim))
        self.dim, self.eps = dim, eps

    def forward(self, x: th.Tensor) -> th.Tensor:
        return F.rms_norm(x, (self.dim,), eps=self.eps) * self.weight


class _EnsembleBlock(nn.Module):
    """Pre-norm Transformer encoder block for ``n`` independent members, input ``(n, B, T, d)``."""

    def __init__(self, n: int, dim: int, n_heads: int, ff_dim: int, activation_fn: type[nn.Module]) -> None:
        super().__init__()
        self.n_heads = n_heads
        self.norm1 = _EnsembleRMSNorm(n, dim)
        self.qkv = _EnsembleLinear(n, dim, 3 * dim)
        self.out = _EnsembleLinear(n, dim, dim)
        self.norm2 = _EnsembleRMSNorm(n, dim)
        self.ff1 = _EnsembleLinear(n, dim, ff_dim)
        self.act = activation_fn()
        self.ff2 = _EnsembleLinear(n, ff_dim, dim)

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
    :param embed_dim: token width ``d``
    :param n_layers: number of Transformer blocks
    :param n_heads: attention heads (must divide ``embed_dim``)
    :param ff_dim: hidden width of the feed-forward sublayer
    :param activation_fn: activation class

    The widths have no defaults here: :class:`~sb3_ua2c.policies.UA2CPolicy` declares them (``critic_*``).
    """

    def __init__(
        self,
        obs_history_dim: int,
        chunk_size: int,
        action_dim: int,
        n_critics: int,
        embed_dim: int,
        n_layers: int,
        n_heads: int,
        ff_dim: int,
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        self.n_critics, self.embed_dim = n_critics, embed_dim
        self.obs_token = _EnsembleLinear(n_critics, obs_history_dim, embed_dim)
        self.action_token = _EnsembleLinear(n_critics, action_dim, embed_dim)
        self.position = nn.Parameter(th.randn(n_critics, 1, chunk_size + 1, embed_dim) * 0.02)
        self.blocks = nn.ModuleList(
            [_EnsembleBlock(n_critics, embed_dim, n_heads, ff_dim, activation_fn) for _ in range(n_layers)]
        )
        self.norm = _EnsembleRMSNorm(n_critics, embed_dim)
        self.head = _EnsembleLinear(n_critics, (chunk_size + 1) * embed_dim, 1)
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


class MLPChunkCritics(nn.Module):
    """
    Twin (``n_critics``) MLP chunk critics ``Q_phi_j(o_{t-ℓ+1:t}, a_{t:t+k-1})`` over the flattened
    (observation history, chunk) input, as Q-chunking's critic (Li et al., 2025), evaluated in one
    batched call: each layer holds the members' weights stacked, ``(n, in, out)``.

    Each hidden layer is linear, then (optionally) a layer norm, then the activation; the value is a
    linear read-out. The first layer is split into a history part, computed once per history, and a
    chunk part, so that the ``C`` candidates of a history share the history's features. Same call as
    :class:`ChunkCritics`.

    :param obs_history_dim: ``ℓ * obs_dim``
    :param chunk_size: ``k``
    :param action_dim: action size
    :param n_critics: number of critics (2 for clipped double-Q)
    :param net_arch: hidden layer sizes (at least one)
    :param layer_norm: a layer norm before each hidden activation (as RLPD's and Q-chunking's critics)
    :param activation_fn: activation class

    The sizes have no defaults here: :class:`~sb3_ua2c.policies.UA2CPolicy` declares them (``critic_*``).
    """

    def __init__(
        self,
        obs_history_dim: int,
        chunk_size: int,
        action_dim: int,
        n_critics: int,
        net_arch: Sequence[int],
        layer_norm: bool,
        activation_fn: type[nn.Module],
    ) -> None:
        super().__init__()
        if len(net_arch) == 0:
            raise ValueError("critic_net_arch must have at least one hidden layer")
        self.n_critics = n_critics
        self.obs_layer = _EnsembleLinear(n_critics, obs_history_dim, net_arch[0])
        self.chunk_layer = _EnsembleLinear(n_critics, chunk_size * action_dim, net_arch[0], bias=False)
        self.hidden = nn.ModuleList(
            [_EnsembleLinear(n_critics, n_in, n_out) for n_in, n_out in zip(net_arch[:-1], net_arch[1:], strict=True)]
        )
        norms = [_EnsembleLayerNorm(n_critics, width) if layer_norm else nn.Identity() for width in net_arch]
        self.norms = nn.ModuleList(norms)
        self.act = activation_fn()
        self.head = _EnsembleLinear(n_critics, net_arch[-1], 1)

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
