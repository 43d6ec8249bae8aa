"""Pure maths of conditional flow matching over action chunks (paper §3.1, Eq. 2).

Chunks have shape ``(batch, k, action_dim)`` everywhere; a flow time ``tau`` has shape ``(batch,)``
and is broadcast over the chunk dimensions. All functions are pure (no module state) so that they
can be tested against hand-computed values.
"""

from __future__ import annotations

from collections.abc import Callable

import torch as th

VelocityFn = Callable[[th.Tensor, th.Tensor], th.Tensor]


def _expand_tau(tau: th.Tensor, like: th.Tensor) -> th.Tensor:
    """Reshape ``tau`` of shape ``like.shape[:tau.ndim]`` so that it broadcasts over ``like``."""
    if tau.shape != like.shape[: tau.ndim]:
        raise ValueError(
            f"tau of shape {tuple(tau.shape)} does not match the leading dims of {tuple(like.shape)}"
        )
    # (batch,) -> (batch, 1, 1) for chunks of shape (batch, k, action_dim)
    return tau.reshape(tau.shape + (1,) * (like.ndim - tau.ndim))


def interpolate(x0: th.Tensor, x1: th.Tensor, tau: th.Tensor) -> th.Tensor:
    """
    Linear probability path of Eq. 2: ``x_tau = (1 - tau) x0 + tau x1``.

    :param x0: noise chunks, shape ``(batch, k, action_dim)``
    :param x1: data chunks, same shape as ``x0``
    :param tau: flow times in [0, 1], shape ``(batch,)``
    :return: interpolated chunks ``x_tau``, shape ``(batch, k, action_dim)``
    """
    t = _expand_tau(tau, x0)
    return (1.0 - t) * x0 + t * x1


def target_velocity(x0: th.Tensor, x1: th.Tensor) -> th.Tensor:
    """
    Regression target of the velocity field in Eq. 2: ``x1 - x0`` (constant along the path).

    :param x0: noise chunks, shape ``(batch, k, action_dim)``
    :param x1: data chunks, same shape
    :return: target velocity, shape ``(batch, k, action_dim)``
    """
    return x1 - x0


def estimate_terminal(x_tau: th.Tensor, tau: th.Tensor, velocity: th.Tensor) -> th.Tensor:
    """
    One-step estimate of the terminal chunk used by the value term of Eq. 2:
    ``x̂1 = x_tau + (1 - tau) v_theta(x_tau, tau | h_t)``.

    :param x_tau: interpolated chunks, shape ``(batch, k, action_dim)``
    :param tau: flow times, shape ``(batch,)``
    :param velocity: predicted velocity at ``(x_tau, tau)``, same shape as ``x_tau``
    :return: ``x̂1``, shape ``(batch, k, action_dim)``
    """
    return x_tau + (1.0 - _expand_tau(tau, x_tau)) * velocity


def flow_matching_loss(
    velocity: th.Tensor,
    x0: th.Tensor,
    x1: th.Tensor,
    mask: th.Tensor | None = None,
    sample_weights: th.Tensor | None = None,
) -> th.Tensor:
    """
    First term of Eq. 2, ``E ||v_theta(x_tau, tau | h_t) - (x1 - x0)||^2``.

    The squared norm is averaged over the ``k * action_dim`` chunk entries (instead of summed) so
    that the weight ``lambda`` of the value term does not change meaning with the chunk size. With a
    ``mask``, the average runs over the valid chunk positions only: the zero padding after an
    episode's end in a logged window is not an action, and regressing on it would teach the actor
    "zero action" near episode ends (Q-chunking masks it too, with its ``valid`` flags, though it
    divides by all entries).

    :param velocity: predicted velocities, shape ``(batch, k, action_dim)``
    :param x0: noise chunks, same shape
    :param x1: data chunks, same shape
    :param mask: 1 at the valid chunk positions, 0 at padding, shape ``(batch, k)``; ``None`` = all valid
    :param sample_weights: a weight per chunk, shape ``(batch,)`` (no gradient; ``None`` = all 1): the
        advantage weights of AWR / IQL's extraction (``actor_extraction="awr"``,
        :func:`~sb3_ua2c.in_sample_maths.advantage_weights`). The average still divides by the number of valid
        entries, as IQL's ``mean(w * log_prob)``, not by the weights' sum
    :return: scalar loss (0 if no position is valid)
    """
    error = (velocity - target_velocity(x0, x1)).pow(2)  # (batch, k, action_dim)
    if sample_weights is not None:
        error = error * sample_weights.detach().reshape(-1, *([1] * (error.ndim - 1)))  # (batch,) -> (batch, 1, 1)
    if mask is None:
        return error.mean()
    weights = mask.to(error.dtype).unsqueeze(-1).expand_as(error)  # (batch, k) -> (batch, k, action_dim)
    return (error * weights).sum() / weights.sum().clamp_min(1.0)


def euler_times(n_steps: int, dtype: th.dtype = th.float32, device: th.device | str = "cpu") -> th.Tensor:
    """
    Flow times of ``n_steps`` explicit Euler steps over [0, 1]: ``tau_i = i / N``, shape ``(N,)``.
    """
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    return th.arange(n_steps, dtype=dtype, device=device) * (1.0 / n_steps)


def euler_sample(
    velocity_fn: VelocityFn, x0: th.Tensor, n_steps: int, step_inputs: th.Tensor | None = None
) -> th.Tensor:
    """
    Integrate ``dx/dtau = v(x, tau)`` from ``tau = 0`` to ``1`` with ``n_steps`` explicit Euler steps.

    :param velocity_fn: maps ``(x, tau)`` with ``x`` of shape ``(*batch, k, action_dim)`` and a
        scalar-valued ``tau`` tensor of shape ``()`` to a velocity of the same shape as ``x``
    :param x0: initial noise, shape ``(*batch, k, action_dim)``
    :param n_steps: number of Euler steps ``N`` (>= 1)
    :param step_inputs: optional ``(N, ...)`` tensor whose row ``i`` replaces ``tau_i`` as the second
        argument of ``velocity_fn`` (e.g. time features of :func:`euler_times` computed once)
    :return: ``x1`` (not clipped), same shape as ``x0``
    """
    if step_inputs is None:
        step_inputs = euler_times(n_steps, x0.dtype, x0.device)  # raises for n_steps < 1
    elif n_steps < 1 or step_inputs.shape[0] != n_steps:
        raise ValueError(
            f"step_inputs must have {n_steps} rows (n_steps >= 1), got {tuple(step_inputs.shape)}"
        )
    x = x0
    dt = 1.0 / n_steps
    for i in range(n_steps):
        x = th.add(x, velocity_fn(x, step_inputs[i]), alpha=dt)  # x + dt * v(x, tau_i)
    return x


def chunk_roughness(chunks: th.Tensor, dims: list[int]) -> th.Tensor:
    """
    Roughness of chunks: the mean squared step change inside each chunk,
    ``mean_{b, i, c} (x[b, i+1, c] - x[b, i, c])^2`` over ``i < k - 1`` and the action dims ``c``
    in ``dims`` (not a term of the paper; see :func:`actor_loss`).

    :param chunks: shape ``(batch, k, action_dim)``
    :param dims: action dims whose changes count (the continuous ones)
    :return: scalar; ``0`` for ``k = 1`` (a one-step chunk has no step inside it) or no ``dims``
    """
    x = chunks[..., dims]  # (B, k, C)
    if x.shape[1] < 2 or x.shape[2] == 0:
        return x.new_zeros(())
    return (x[:, 1:] - x[:, :-1]).pow(2).mean()


def actor_loss(
    velocity: th.Tensor,
    x0: th.Tensor,
    x1: th.Tensor,
    q_values: th.Tensor,
    q_weight: float,
    smooth_weight: float,
    normalize_q: bool,
    roughness: th.Tensor | None = None,
    mask: th.Tensor | None = None,
) -> tuple[th.Tensor, dict[str, float]]:
    """
    Actor objective of Eq. 2: ``E||v - (x1 - x0)||^2 - lambda * E[min_j Q_j(o-history, x̂1)]``,
    plus ``mu * roughness(x̂1)`` when ``smooth_weight = mu > 0``.

    With ``normalize_q`` the value term is divided by the (detached) mean ``|Q|`` of the batch, as in
    TD3+BC, so that ``lambda`` is dimensionless and does not depend on the reward scale of the
    environment (:func:`value_term`).
    The smoothness term is not in the paper (``mu = 0`` is Eq. 2): it penalises step changes inside
    the terminal estimate ``x̂1`` (:func:`chunk_roughness`), so a ``k = 1`` policy is not affected.

    :param velocity: ``v_theta(x_tau, tau | h_t)``, shape ``(batch, k, action_dim)``
    :param x0: noise chunks, same shape
    :param x1: data chunks, same shape
    :param q_values: ``min_j Q_j(o-history, x̂1)`` (critics frozen), shape ``(batch,)``
    :param q_weight: ``lambda`` (>= 0)
    :param smooth_weight: ``mu`` (>= 0)
    :param normalize_q: divide the value term by the batch mean ``|Q|`` (:func:`value_term`)
    :param roughness: :func:`chunk_roughness` of ``x̂1`` (scalar), needed when ``smooth_weight > 0``
    :param mask: valid chunk positions of ``x1``, shape ``(batch, k)`` (:func:`flow_matching_loss`);
        ``None`` = all valid
    :return: scalar loss and a dict of logged floats (``flow_loss``, ``q_term``, ``q_scale``, and
        ``roughness`` when ``mu > 0``)
    """
    flow = flow_matching_loss(velocity, x0, x1, mask)
    q_term, q_scale = value_term(q_values, normalize_q)
    loss = flow + q_weight * q_term
    info = {"flow_loss": flow.item(), "q_term": q_term.item(), "q_scale": q_scale.item()}
    if smooth_weight > 0.0:
        if roughness is None:
            raise ValueError("actor_loss: smooth_weight > 0 needs the roughness of x̂1")
        loss = loss + smooth_weight * roughness
        info["roughness"] = roughness.item()
    return loss, info


def value_term(q_values: th.Tensor, normalize_q: bool) -> tuple[th.Tensor, th.Tensor]:
    """
    The value term of the actor objectives, ``-E[Q]``, divided by the detached batch mean ``|Q|`` with
    ``normalize_q`` (TD3+BC's normalisation, Fujimoto & Gu, 2021), raw without it (FQL's and
    QC-FQL's default, ``normalize_q_loss=False``).

    :param q_values: values of the actor's chunks, shape ``(batch,)``
    :param normalize_q: divide by the batch mean ``|Q|``
    :return: the term (scalar) and the batch mean ``|Q|`` (detached, at least 1e-6; logged either way)
    """
    q_scale = q_values.detach().abs().mean().clamp_min(1e-6)
    mean = q_values.mean()
    return (-mean / q_scale if normalize_q else -mean), q_scale


def distillation_loss(one_step_chunks: th.Tensor, flow_chunks: th.Tensor) -> th.Tensor:
    """
    Distillation of the flow into the one-step policy (QC-FQL, Li et al., 2025, after FQL, Park et
    al., 2025): ``E ||mu(h, z) - flow(h, z)||^2``, averaged over the batch and the ``k * action_dim``
    chunk entries, with ``flow(h, z)`` the flow's Euler sample from the same noise ``z`` (no gradient).

    :param one_step_chunks: ``mu(h, z)``, shape ``(batch, k, action_dim)``
    :param flow_chunks: ``flow(h, z)``, same shape (detached here)
    :return: scalar loss
    """
    return (one_step_chunks - flow_chunks.detach()).pow(2).mean()


def one_step_actor_loss(
    flow_loss: th.Tensor,
    one_step_chunks: th.Tensor,
    flow_chunks: th.Tensor,
    q_values: th.Tensor,
    q_weight: float,
    distill_weight: float,
    normalize_q: bool,
) -> tuple[th.Tensor, dict[str, float]]:
    """
    QC-FQL's actor objective (``actor_type="distill-ddpg"`` of Q-chunking, Li et al., 2025): the flow
    trained by flow matching alone, the one-step policy ``mu`` by distillation and the value term,
    ``flow_loss + alpha * E||mu(h, z) - flow(h, z)||^2 - lambda * E[Q(h, clip(mu(h, z)))]``. The
    three networks' parameters are disjoint (the critics are frozen), so one sum trains both actors.

    :param flow_loss: :func:`flow_matching_loss` of the flow on the batch (scalar)
    :param one_step_chunks: ``mu(h, z)``, shape ``(batch, k, action_dim)``
    :param flow_chunks: ``flow(h, z)``, same shape (:func:`distillation_loss`)
    :param q_values: the critics' aggregate of ``Q(h, clip(mu(h, z)))`` (critics frozen), shape ``(batch,)``
    :param q_weight: ``lambda`` (>= 0)
    :param distill_weight: ``alpha`` (>= 0)
    :param normalize_q: divide the value term by the batch mean ``|Q|`` (:func:`value_term`)
    :return: scalar loss and the logged floats ``flow_loss``, ``distill_loss``, ``q_term``, ``q_scale``
    """
    distill = distillation_loss(one_step_chunks, flow_chunks)
    q_term, q_scale = value_term(q_values, normalize_q)
    loss = flow_loss + distill_weight * distill + q_weight * q_term
    info = {"flow_loss": flow_loss.item(), "distill_loss": distill.item(), "q_term": q_term.item(),
            "q_scale": q_scale.item()}
    return loss, info


def drop_past_actions(
    action_history: th.Tensor, p: float, generator: th.Generator | None = None
) -> th.Tensor:
    """
    History dropout against copycat behaviour cloning (Wen et al., NeurIPS 2020, "Fighting Copycat
    Agents in Behavioral Cloning from Observation Histories"; de Haan et al., NeurIPS 2019): each
    sample's past actions are zeroed with probability ``p``, all of them or none. With ``p = 0``
    nothing is drawn (the random stream does not move) and the input is returned as it is.

    :param action_history: ``(batch, ℓ, action_dim)``
    :param p: dropout probability in ``[0, 1]``
    :param generator: the random stream (``None``: torch's global one, as the rest of training)
    :return: ``(batch, ℓ, action_dim)``, the dropped samples' rows all zero
    """
    if p == 0.0:
        return action_history
    u = th.rand(action_history.shape[0], generator=generator).to(action_history.device)  # (batch,)
    keep = (u >= p).to(action_history.dtype)
    return action_history * keep.reshape(-1, *([1] * (action_history.ndim - 1)))
