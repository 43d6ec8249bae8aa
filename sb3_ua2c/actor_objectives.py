"""The actor objectives of UA2C on a batch, one per ``actor_type`` of the policy: the paper's Eq. 2
(:func:`flow_objective`) and QC-FQL's one-step policy (:func:`one_step_objective`). Both see the
histories with their past actions dropped by ``past_action_dropout`` (:func:`~sb3_ua2c.flow.drop_past_actions`)
and value their chunks, clipped to the bounds, with the frozen critics. The maths is in :mod:`sb3_ua2c.flow`.

``UA2C`` trains with :func:`actor_objective`; the diagnostics (:func:`~sb3_ua2c.diagnostics.value_term_strength`)
evaluate the same objective with their own random generator and with ``q_weight = 0``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import torch as th

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

if TYPE_CHECKING:  # UA2C imports this module: its annotations name the base class (no import cycle)
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm as UA2C

    from sb3_ua2c.buffers import ChunkReplaySamples


class ActorObjective(NamedTuple):
    """An actor objective on a batch."""

    #: the scalar loss
    loss: th.Tensor
    #: logged floats (``flow_loss``, ``q_term``, ``q_scale``, ...)
    info: dict[str, float]
    #: the chunks the value term values, before clipping, ``(B, k, A)``: x̂1 (``"flow"``) or ``mu(h, z)``
    chunks: th.Tensor


def _normal(like: th.Tensor, generator: th.Generator | None) -> th.Tensor:
    if generator is None:
        return th.randn_like(like)
    return th.randn(like.shape, generator=generator, dtype=like.dtype).to(like.device)


def _uniform(n: int, like: th.Tensor, generator: th.Generator | None) -> th.Tensor:
    if generator is None:
        return th.rand(n, device=like.device)
    return th.rand(n, generator=generator).to(like.device)


def _frozen_q(model: UA2C, obs_flat: th.Tensor, chunks: th.Tensor) -> th.Tensor:
    """``min_j Q_j(h, clip(chunks))`` with the critics frozen (the value term does not train them):
    ``(B, ℓ*obs_dim), (B, k, A) -> (B,)``; clipped as FQL / Q-chunking clip before Q (no gradient outside)."""
    model.critic.requires_grad_(False)
    try:
        q = model.critic(obs_flat, chunks.clamp(-1.0, 1.0).unsqueeze(1))[:, :, 0]  # (n, B, 1) -> (n, B)
    finally:
        model.critic.requires_grad_(True)
    return pessimistic_q(q)  # (n, B) -> (B,)


def _flow_matching(
    model: UA2C, data: ChunkReplaySamples, generator: th.Generator | None
) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
    """Noise, flow times, dropped past actions and the velocity field's prediction on the batch:
    ``x0 (B, k, A), tau (B,), x_tau (B, k, A), velocity (B, k, A), action_history (B, ℓ, A)``."""
    x1 = data.chunks
    x0 = _normal(x1, generator)
    tau = _uniform(x1.shape[0], x1, generator)
    actions = drop_past_actions(data.action_history, model.past_action_dropout, generator)
    x_tau = interpolate(x0, x1, tau)
    velocity = model.actor(x_tau, tau, model.policy.condition(data.observation_history, actions))
    return x0, tau, x_tau, velocity, actions


def flow_objective(
    model: UA2C, data: ChunkReplaySamples, q_weight: float, generator: th.Generator | None = None
) -> ActorObjective:
    """
    Eq. 2 (``actor_type="flow"``): flow matching on the batch's chunks (masked on window padding) and
    ``-λ Q`` of the one-step terminal estimate x̂1 (:func:`~sb3_ua2c.flow.actor_loss`).

    :param model: the model (actor, critics, ``smooth_weight``, ``normalize_q``, ``past_action_dropout``)
    :param data: the batch
    :param q_weight: ``λ``
    :param generator: the random stream of ``x0``, ``tau`` and the dropout (``None``: torch's global one)
    """
    x0, tau, x_tau, velocity, _ = _flow_matching(model, data, generator)
    x_hat = estimate_terminal(x_tau, tau, velocity)
    q = _frozen_q(model, data.observation_history.flatten(1), x_hat)
    roughness = chunk_roughness(x_hat, model.policy.continuous_dims) if model.smooth_weight > 0.0 else None
    loss, info = actor_loss(velocity, x0, data.chunks, q, q_weight, roughness, model.smooth_weight,
                            data.chunk_mask, model.normalize_q)
    return ActorObjective(loss, info, x_hat)


def one_step_objective(
    model: UA2C, data: ChunkReplaySamples, q_weight: float, generator: th.Generator | None = None
) -> ActorObjective:
    """
    QC-FQL (``actor_type="one_step"``): the flow by flow matching alone, the one-step policy
    ``mu(h, z)`` by ``distill_weight`` times the distance to the flow's ``flow_steps`` Euler sample
    from the same ``z`` and ``-λ Q(h, clip(mu(h, z)))`` (:func:`~sb3_ua2c.flow.one_step_actor_loss`;
    with ``smooth_weight > 0``, plus the roughness of ``mu(h, z)``).

    :param model: the model
    :param data: the batch
    :param q_weight: ``λ``
    :param generator: the random stream of ``x0``, ``tau``, the dropout and ``z`` (``None``: torch's global one)
    """
    policy = model.policy
    x0, _, _, velocity, actions = _flow_matching(model, data, generator)
    flow = flow_matching_loss(velocity, x0, data.chunks, data.chunk_mask)
    z = _normal(data.chunks, generator)  # (B, k, A)
    with th.no_grad():
        target = policy.flow_sample(data.observation_history, actions, z, policy.flow_steps)  # (B, k, A)
    mu = policy.one_step_actor(policy.flatten_history(data.observation_history, actions), z)  # (B, k, A)
    q = _frozen_q(model, data.observation_history.flatten(1), mu)
    loss, info = one_step_actor_loss(flow, mu, target, q, q_weight, model.distill_weight, model.normalize_q)
    if model.smooth_weight > 0.0:
        roughness = chunk_roughness(mu, policy.continuous_dims)
        loss = loss + model.smooth_weight * roughness
        info["roughness"] = roughness.item()
    return ActorObjective(loss, info, mu)


#: the actor objective of each ``actor_type``
OBJECTIVES = {"flow": flow_objective, "one_step": one_step_objective}


def actor_objective(
    model: UA2C, data: ChunkReplaySamples, q_weight: float | None = None, generator: th.Generator | None = None
) -> ActorObjective:
    """
    The actor objective of the model's ``actor_type`` on a batch.

    :param model: the model
    :param data: the batch (histories, chunks, ``chunk_mask``)
    :param q_weight: ``λ`` (``None``: the model's ``q_weight``)
    :param generator: the random stream (``None``: torch's global one, as in training)
    """
    weight = model.q_weight if q_weight is None else q_weight
    return OBJECTIVES[model.policy.actor_type](model, data, weight, generator)
