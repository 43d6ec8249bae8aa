"""The chunk actors of UA2C, by name: ``policy_kwargs["actor_type"]`` picks a class of :data:`ACTORS`.
The policy asks an actor for the interface of :class:`ChunkActor` only, and training for its
``objective`` (:func:`actor_objective`).

Every policy holds the velocity field of Eq. 2 as ``actor`` (:class:`~sb3_ua2c.actors.flow.VelocityField`):
each actor kind learns it by flow matching. The kind of ``actor_type`` is the network that turns noise
into candidate chunks: the velocity field itself (``"flow"``), or a network of its own stored under its
``attribute`` (``"one_step"``: ``one_step_actor``, QC-FQL's policy distilled from the flow). A new
actor is one module with one class and one line in :data:`ACTORS` (docs/algorithm.md, "Adding a
critic or an actor").
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

import torch as th
from torch import nn

from sb3_ua2c.actor_objectives import ActorBatch, ActorInputs, ActorObjective, ActorWeights
from sb3_ua2c.actors.flow import VelocityField
from sb3_ua2c.actors.one_step import OneStepActor


class ChunkActor(Protocol):
    """
    The interface of an actor class of :data:`ACTORS`: an ``nn.Module`` built as
    ``cls(history_dim, chunk_size, action_dim, net_arch, activation_fn)``.
    """

    #: the policy attribute that holds it, its state-dict prefix (``"actor"``: the velocity field itself)
    attribute: ClassVar[str]
    #: its objective on a batch, ``(ActorInputs, ActorBatch, ActorWeights, generator) -> ActorObjective``
    #: (:mod:`sb3_ua2c.actor_objectives`)
    objective: ClassVar[Any]

    def sample(self, history: th.Tensor, noise: th.Tensor, n_steps: int) -> th.Tensor:
        """
        :param history: flattened histories, ``(B, history_dim)`` (:func:`~sb3_ua2c.actor_objectives.actor_history`)
        :param noise: ``(B, *extra, k, action_dim)``
        :param n_steps: Euler steps of a flow (an actor without steps ignores it)
        :return: unclipped chunks, the shape of ``noise``
        """


#: the actors by ``actor_type``: the paper's flow, or QC-FQL's one-step policy distilled from it
ACTORS: dict[str, type[nn.Module]] = {
    "flow": VelocityField,
    "one_step": OneStepActor,
}


def actor_class(actor_type: str) -> Any:
    """
    :param actor_type: a key of :data:`ACTORS`
    :return: its class
    """
    if not isinstance(actor_type, str) or actor_type not in ACTORS:
        raise ValueError(f"actor_type must be one of {list(ACTORS)}, got {actor_type!r}")
    return ACTORS[actor_type]


def actor_objective(
    actor_type: str,
    inputs: ActorInputs,
    data: ActorBatch,
    weights: ActorWeights,
    generator: th.Generator | None = None,
) -> ActorObjective:
    """
    The objective of ``actor_type``'s class on a batch (training and the diagnostics call this one).

    :param actor_type: a key of :data:`ACTORS`
    :param inputs: the networks and how they read histories (``UA2CPolicy.actor_inputs``)
    :param data: the batch (histories, chunks, ``chunk_mask``)
    :param weights: the objective's weights (``UA2C.actor_weights``)
    :param generator: the random stream (``None``: torch's global one, as in training)
    """
    return actor_class(actor_type).objective(inputs, data, weights, generator)


__all__ = ["ACTORS", "ChunkActor", "OneStepActor", "VelocityField", "actor_class", "actor_objective"]
