"""QC-FQL's one-step policy (Q-chunking, Li et al., 2025; FQL, Park et al., 2025), distilled from the
flow and trained against Q, ``actor_type="one_step"`` (:data:`~sb3_ua2c.actors.ACTORS`).
"""

from __future__ import annotations

from typing import ClassVar

import torch as th
from torch import nn

from sb3_ua2c.actor_objectives import one_step_objective
from sb3_ua2c.actors.flow import mlp_trunk


class OneStepActor(nn.Module):
    """
    QC-FQL's one-step policy ``mu(h, z)`` (Q-chunking, Li et al., 2025; FQL, Park et al., 2025): an MLP
    from a history and a noise chunk ``z`` to a chunk in one call, distilled from the flow and trained
    against Q (:func:`~sb3_ua2c.flow.one_step_actor_loss`). As in :class:`~sb3_ua2c.actors.flow.VelocityField`, the first layer
    is split into a history part, computed once per history, and a noise part, so that S candidates
    reuse the history features.

    :param history_dim: size of the flattened history (the velocity field's input)
    :param chunk_size: ``k``
    :param action_dim: action size
    :param net_arch: hidden layer sizes (at least one; the velocity field's)
    :param activation_fn: activation class
    """

    #: the policy attribute (state-dict prefix) of this actor (the flow stays ``actor``)
    attribute: ClassVar[str] = "one_step_actor"
    #: its objective: flow matching, distillation and the value term
    objective = staticmethod(one_step_objective)

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
        self.trunk = mlp_trunk(net_arch, chunk_dim, activation_fn)

    def forward(self, history: th.Tensor, z: th.Tensor) -> th.Tensor:
        """
        :param history: flattened histories, shape ``(batch, history_dim)``
        :param z: noise chunks, shape ``(batch, *extra, k, action_dim)``
        :return: chunks (not clipped), same shape as ``z``
        """
        first = self.history_layer(history)  # (batch, hidden)
        first = first.reshape(first.shape[0], *([1] * (z.ndim - 3)), first.shape[-1])  # (batch, *[1]*extra, hidden)
        return self.trunk(self.noise_layer(z.flatten(-2)) + first).reshape(z.shape)

    def sample(self, history: th.Tensor, noise: th.Tensor, n_steps: int) -> th.Tensor:
        """
        Candidate chunks in one call, ``mu(h, z)``.

        :param history: flattened histories, shape ``(batch, history_dim)``
        :param noise: ``z``, shape ``(batch, *extra, k, action_dim)``
        :param n_steps: not used (one step)
        :return: chunks (not clipped), the shape of ``noise``
        """
        return self(history, noise)


__all__ = ["OneStepActor"]
