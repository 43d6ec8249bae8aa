"""The actor objectives of UA2C on a batch, one per actor class (:data:`~sb3_ua2c.actors.ACTORS`): the
paper's Eq. 2 (:func:`flow_objective`) and QC-FQL's one-step policy (:func:`one_step_objective`). Both
see the histories with their past actions dropped by ``past_action_dropout``
(:func:`~sb3_ua2c.flow.drop_past_actions`) and value their chunks, clipped to the bounds, with the
frozen critics. The maths is in :mod:`sb3_ua2c.flow`.

An objective takes its inputs explicitly: the networks (:class:`ActorInputs`), the batch and the
weights (:class:`ActorWeights`). ``UA2C`` trains with :func:`~sb3_ua2c.actors.actor_objective`; the
diagnostics (:func:`~sb3_ua2c.diagnostics.value_term_strength`) evaluate the same objective with their
own random generator and with ``q_weight = 0``.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import torch as th
from torch import nn

from sb3_ua2c.chunking import pessimistic_q
from sb3_ua2c.flow import (
    actor_loss,
    chunk_roughness,
    drop_past_actions,
    estimate_terminal,
    flow_matching_loss,
    interpolate,
    one_step_actor_loss,
)


class ActorObjective(NamedTuple):
    """An actor objective on a batch."""

    #: the scalar loss
    loss: th.Tensor
    #: logged floats (``flow_loss``, ``q_term``, ``q_scale``, ...)
    info: dict[str, float]
    #: the chunks the value term values, before clipping, ``(B, k, A)``: x̂1 (``"flow"``) or ``mu(h, z)``
    chunks: th.Tensor


class ActorBatch(Protocol):
    """The batch tensors an actor objective reads (a :class:`~sb3_ua2c.buffers.ChunkReplaySamples` has them)."""

    #: ``(B, ℓ, obs_dim)``
    observation_history: th.Tensor
    #: ``(B, ℓ, action_dim)``
    action_history: th.Tensor
    #: the logged chunks ``x1``, ``(B, k, action_dim)``
    chunks: th.Tensor
    #: valid positions of ``chunks``, ``(B, k)`` (``None``: all)
    chunk_mask: th.Tensor | None


class ActorInputs(NamedTuple):
    """The networks an actor objective reads, and how the actors read a history (``UA2CPolicy.actor_inputs``)."""

    #: the velocity field of Eq. 2 (the policy's ``actor``), trained by flow matching under every actor kind
    flow: nn.Module
    #: the network the value term trains: the velocity field itself, or the actor kind's own network
    actor: nn.Module
    #: the online critics, ``(B, ℓ*obs_dim), (B, C, k, A) -> (n, B, C)`` (frozen inside the objective)
    critic: nn.Module
    #: the actors read the past actions of a history (``actor_past_actions``)
    past_actions: bool
    #: the continuous action dims (the smoothness term's)
    continuous_dims: list[int]
    #: Euler steps of the flow's sample that the one-step policy is distilled to (``flow_steps``)
    flow_steps: int


class ActorWeights(NamedTuple):
    """The weights of an actor objective (UA2C's arguments of the same names)."""

    #: ``λ``, the value term's
    q_weight: float
    #: ``mu``, the in-chunk smoothness term's
    smooth_weight: float
    #: divide the value term by the batch mean ``|Q|``
    normalize_q: bool
    #: ``alpha``, the distillation's (one-step policy only)
    distill_weight: float
    #: ``p`` of the history dropout
    past_action_dropout: float


def actor_history(obs_history: th.Tensor, action_history: th.Tensor, past_actions: bool) -> th.Tensor:
    """
    The actors' input: ``(B, ℓ, obs_dim)`` and ``(B, ℓ, action_dim)`` -> ``(B, ℓ*(obs_dim+action_dim))``,
    or ``(B, ℓ*obs_dim)`` without the past actions.

    :param obs_history: ``(B, ℓ, obs_dim)``
    :param action_history: ``(B, ℓ, action_dim)``
    :param past_actions: include the past actions (``actor_past_actions``)
    """
    b = obs_history.shape[0]
    if not past_actions:
        return obs_history.reshape(b, -1)
    return th.cat([obs_history.reshape(b, -1), action_history.reshape(b, -1)], dim=1)


def _normal(like: th.Tensor, generator: th.Generator | None) -> th.Tensor:
    if generator is None:
        return th.randn_like(like)
    return th.randn(like.shape, generator=generator, dtype=like.dtype).to(like.device)


def _uniform(n: int, like: th.Tensor, generator: th.Generator | None) -> th.Tensor:
    if generator is None:
        return th.rand(n, device=like.device)
    return th.rand(n, generator=generator).to(like.device)


def _frozen_q(critic: nn.Module, obs_flat: th.Tensor, chunks: th.Tensor) -> th.Tensor:
    """``min_j Q_j(h, clip(chunks))`` with the critics frozen (the value term does not train them):
    ``(B, ℓ*obs_dim), (B, k, A) -> (B,)``; clipped as FQL / Q-chunking clip before Q (no gradient outside)."""
    critic.requires_grad_(False)
    try:
        q = critic(obs_flat, chunks.clamp(-1.0, 1.0).unsqueeze(1))[:, :, 0]  # (n, B, 1) -> (n, B)
    finally:
        critic.requires_grad_(True)
    return pessimistic_q(q)  # (n, B) -> (B,)


def _flow_matching(
    inputs: ActorInputs, data: ActorBatch, dropout: float, generator: th.Generator | None
) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
    """Noise, flow times, the actors' (dropped) histories and the velocity field's prediction on the batch:
    ``x0 (B, k, A), tau (B,), x_tau (B, k, A), velocity (B, k, A), history (B, history_dim)``."""
    x1 = data.chunks
    x0 = _normal(x1, generator)
    tau = _uniform(x1.shape[0], x1, generator)
    actions = drop_past_actions(data.action_history, dropout, generator)
    history = actor_history(data.observation_history, actions, inputs.past_actions)
    x_tau = interpolate(x0, x1, tau)
    velocity = inputs.flow(x_tau, tau, inputs.flow.condition(history))
    return x0, tau, x_tau, velocity, history


def flow_objective(
    inputs: ActorInputs, data: ActorBatch, weights: ActorWeights, generator: th.Generator | None
) -> ActorObjective:
    """
    Eq. 2 (``actor_type="flow"``): flow matching on the batch's chunks (masked on window padding) and
    ``-λ Q`` of the one-step terminal estimate x̂1 (:func:`~sb3_ua2c.flow.actor_loss`).

    :param inputs: the velocity field and the critics
    :param data: the batch
    :param weights: ``q_weight``, ``smooth_weight``, ``normalize_q``, ``past_action_dropout``
    :param generator: the random stream of ``x0``, ``tau`` and the dropout (``None``: torch's global one)
    """
    x0, tau, x_tau, velocity, _ = _flow_matching(inputs, data, weights.past_action_dropout, generator)
    x_hat = estimate_terminal(x_tau, tau, velocity)
    q = _frozen_q(inputs.critic, data.observation_history.flatten(1), x_hat)
    mu = weights.smooth_weight
    roughness = chunk_roughness(x_hat, inputs.continuous_dims) if mu > 0.0 else None
    loss, info = actor_loss(velocity, x0, data.chunks, q, weights.q_weight, mu, weights.normalize_q,
                            roughness, data.chunk_mask)
    return ActorObjective(loss, info, x_hat)


def advantage_weighted_objective(
    inputs: ActorInputs,
    data: ActorBatch,
    weights: ActorWeights,
    sample_weights: th.Tensor,
    generator: th.Generator | None,
) -> ActorObjective:
    """
    Advantage-weighted flow matching (``actor_extraction="awr"``, not in the paper; AWR, Peng et al., 2019,
    as IQL's extraction, Kostrikov et al., 2022, for a flow as IFQL, Park et al., 2025): the flow-matching
    error of each data chunk weighted by ``sample_weights`` (:func:`~sb3_ua2c.flow.flow_matching_loss`,
    mask honoured) and no value term; with ``smooth_weight > 0``, plus the roughness of x̂1.

    :param inputs: the velocity field
    :param data: the batch
    :param weights: ``smooth_weight``, ``past_action_dropout`` (``q_weight`` and ``normalize_q`` are not read)
    :param sample_weights: one weight per chunk, ``(B,)`` (:func:`~sb3_ua2c.in_sample_maths.advantage_weights`)
    :param generator: the random stream of ``x0``, ``tau`` and the dropout (``None``: torch's global one)
    """
    x0, tau, x_tau, velocity, _ = _flow_matching(inputs, data, weights.past_action_dropout, generator)
    loss = flow_matching_loss(velocity, x0, data.chunks, data.chunk_mask, sample_weights)
    info = {"flow_loss": loss.item()}
    x_hat = estimate_terminal(x_tau, tau, velocity)
    if weights.smooth_weight > 0.0:
        roughness = chunk_roughness(x_hat, inputs.continuous_dims)
        loss = loss + weights.smooth_weight * roughness
        info["roughness"] = roughness.item()
    return ActorObjective(loss, info, x_hat)


def one_step_objective(
    inputs: ActorInputs, data: ActorBatch, weights: ActorWeights, generator: th.Generator | None
) -> ActorObjective:
    """
    QC-FQL (``actor_type="one_step"``): the flow by flow matching alone, the one-step policy
    ``mu(h, z)`` by ``distill_weight`` times the distance to the flow's ``flow_steps`` Euler sample
    from the same ``z`` and ``-λ Q(h, clip(mu(h, z)))`` (:func:`~sb3_ua2c.flow.one_step_actor_loss`;
    with ``smooth_weight > 0``, plus the roughness of ``mu(h, z)``).

    :param inputs: the velocity field, the one-step policy (``inputs.actor``) and the critics
    :param data: the batch
    :param weights: all of :class:`ActorWeights`
    :param generator: the random stream of ``x0``, ``tau``, the dropout and ``z`` (``None``: torch's global one)
    """
    x0, _, _, velocity, history = _flow_matching(inputs, data, weights.past_action_dropout, generator)
    flow = flow_matching_loss(velocity, x0, data.chunks, data.chunk_mask)
    z = _normal(data.chunks, generator)  # (B, k, A)
    with th.no_grad():
        target = inputs.flow.sample(history, z, inputs.flow_steps)  # (B, k, A)
    mu = inputs.actor.sample(history, z, inputs.flow_steps)  # (B, k, A)
    q = _frozen_q(inputs.critic, data.observation_history.flatten(1), mu)
    loss, info = one_step_actor_loss(flow, mu, target, q, weights.q_weight, weights.distill_weight,
                                     weights.normalize_q)
    if weights.smooth_weight > 0.0:
        roughness = chunk_roughness(mu, inputs.continuous_dims)
        loss = loss + weights.smooth_weight * roughness
        info["roughness"] = roughness.item()
    return ActorObjective(loss, info, mu)


__all__ = [
    "ActorBatch",
    "ActorInputs",
    "ActorObjective",
    "ActorWeights",
    "actor_history",
    "advantage_weighted_objective",
    "flow_objective",
    "one_step_objective",
]
