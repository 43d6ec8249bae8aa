"""The paper's flow-matching chunk actor (Eq. 2): the velocity field ``v_theta(x_tau, tau | h_t)`` and its
Euler sampler, ``actor_type="flow"`` (:data:`~sb3_ua2c.actors.ACTORS`).

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.1-3.2.
"""

from __future__ import annotations

from typing import ClassVar

import torch as th
from torch import nn

from sb3_ua2c.actor_objectives import flow_objective
from sb3_ua2c.flow import euler_sample, euler_times


def mlp_trunk(net_arch: list[int], out_dim: int, activation_fn: type[nn.Module]) -> nn.Sequential:
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
    It is the policy's ``actor`` under every ``actor_type`` (each learns it by flow matching) and the
    actor that acts under ``actor_type="flow"`` (:data:`~sb3_ua2c.actors.ACTORS`).
    """

    #: the policy attribute (state-dict prefix) of this actor
    attribute: ClassVar[str] = "actor"
    #: its objective: Eq. 2
    objective = staticmethod(flow_objective)

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
        self.trunk = mlp_trunk(net_arch, chunk_dim, activation_fn)

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

    def sample(self, history: th.Tensor, noise: th.Tensor, n_steps: int) -> th.Tensor:
        """
        Candidate chunks: ``n_steps`` Euler steps of the flow from ``noise`` (:meth:`integrate`).

        :param history: flattened histories, shape ``(batch, history_dim)``
        :param noise: ``x0``, shape ``(batch, *extra, k, action_dim)``
        :param n_steps: Euler steps ``N``
        :return: ``x1`` (not clipped), the shape of ``noise``
        """
        return self.integrate(noise, self.condition(history), n_steps)

    def integrate(self, x0: th.Tensor, cond: th.Tensor, n_steps: int) -> th.Tensor:
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


__all__ = ["VelocityField", "mlp_trunk"]
