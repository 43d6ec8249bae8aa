"""Diagnostics of a UA2C model on histories of a dataset: does the plan follow the observations or
copy the past actions, does the value term of Eq. 2 move the actor, can the critics rank the
candidates of a replanning, and does the bootstrap of Eq. 4 / 8 value the policy that acts.

``python -m sb3_ua2c.diagnostics CHECKPOINT DATASET [--n-histories N --seed S --json OUT]`` prints
them for a checkpoint and an offline dataset (:mod:`sb3_ua2c.offline`); docs/diagnostics.md says
what each number means and what a healthy value looks like. During training, ``UA2C`` logs
:func:`critic_fit` at every update and :func:`training_diagnostics` every
:data:`DIAGNOSTICS_INTERVAL` updates (``train/td_rmse``, ``train/twin_gap``, ``train/q_grad_ratio``,
``train/candidate_q_std``, ``train/twin_agreement``).

The tensor functions are pure; the model-level ones draw their noise from a ``th.Generator`` they
are given, so they never move the global random streams a training run depends on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import torch as th

from sb3_ua2c.actor_objectives import ActorObjective
from sb3_ua2c.actors import actor_objective
from sb3_ua2c.chunking import bootstrap_value, chunk_target, pessimistic_q, select_chunk

if TYPE_CHECKING:
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm as UA2C

    from sb3_ua2c.buffers import ChunkReplaySamples
    from sb3_ua2c.policies import UA2CPolicy

#: updates between two :func:`training_diagnostics` during training (``train/q_grad_ratio`` ...)
DIAGNOSTICS_INTERVAL = 250
#: histories of the batch that :func:`training_diagnostics` replans
TRAINING_HISTORIES = 64

#: ``{metric: (what it measures, a healthy value)}``, in the order the command prints them
METRICS: dict[str, tuple[str, str]] = {
    "sensitivity_past_actions": ("mean |Δ planned first action| when the past actions are another history's",
                                 "below sensitivity_observations"),
    "sensitivity_observations": ("mean |Δ planned first action| when the observations are another history's",
                                 "clearly above 0"),
    "correlation_policy": ("corr(last past action, planned first action)", "close to correlation_data"),
    "correlation_data": ("corr(last past action, next action) in the dataset", "the reference"),
    "q_grad_norm": ("norm of the value term's gradient (λ · Q term of Eq. 2) w.r.t. the actor", "sets the scale"),
    "flow_grad_norm": ("norm of the flow-matching term's gradient w.r.t. the actor", "sets the scale"),
    "q_grad_ratio": ("q_grad_norm / flow_grad_norm", "0.1 .. 1"),
    "x_hat_shift": ("mean |Δx̂1| of an Adam-like step of the value term, action units", "well above 0.01"),
    "candidate_q_std": ("std of min_j Q_j over the candidates of a replanning", "above td_rmse"),
    "td_rmse": ("RMSE of the critics against their target (Eq. 4 / 8)", "below candidate_q_std"),
    "twin_gap": ("mean |Q_1 - Q_2| on the batch's chunks", "below candidate_q_std"),
    "twin_agreement": ("fraction of states where every critic picks the same best candidate", "≥ 0.5"),
    "acting_value": ("min_j Q̄_j of the chunk the policy acts with (elite mean, flow_steps)", "sets the scale"),
    "bootstrap_value": ("max over n_target_candidates of min_j Q̄_j (target_flow_steps)", "sets the scale"),
    "policy_gap": ("acting_value - bootstrap_value", "about 0"),
    "spread_ratio": ("candidate std at target_flow_steps / at flow_steps, same noise", "about 1"),
}


# ---------------------------------------------------------------------------- pure tensor maths
def mean_abs_shift(a: th.Tensor, b: th.Tensor, dims: Sequence[int]) -> float:
    """
    ``mean |a - b|`` over the rows and the action dims ``dims``.

    :param a: actions, shape ``(m, action_dim)``
    :param b: actions, same shape
    :param dims: the dims that count (the continuous ones); none gives ``nan``
    :return: action units; 0 if ``a`` does not depend on what differs between the two
    """
    if len(dims) == 0:
        return math.nan
    return (a[:, list(dims)] - b[:, list(dims)]).abs().mean().item()


def correlation(x: th.Tensor, y: th.Tensor, dims: Sequence[int]) -> float:
    """
    Pearson correlation of ``x`` and ``y`` over the rows, averaged over the action dims ``dims``.

    :param x: shape ``(m, action_dim)``
    :param y: same shape
    :param dims: the dims that count; none, or a constant dim, gives ``nan``
    :return: in ``[-1, 1]``
    """
    values = []
    for d in dims:
        xd, yd = x[:, d] - x[:, d].mean(), y[:, d] - y[:, d].mean()
        denominator = (xd.pow(2).sum() * yd.pow(2).sum()).sqrt()
        values.append((xd * yd).sum().item() / denominator.item() if denominator > 0 else math.nan)
    return sum(values) / len(values) if values else math.nan


def candidate_q_std(q: th.Tensor) -> float:
    """
    The spread the critics see among the candidates of a replanning: the standard deviation (over
    the ``S`` candidates, unbiased) of ``min_j Q_j``, averaged over the states.

    Healthy: above the critics' own error (:func:`critic_fit`'s ``td_rmse`` and ``twin_gap``); below
    it, best-of-S and elite selection choose on noise.

    :param q: values of every critic, shape ``(n_critics, m, S)``
    :return: same units as Q; 0 for a critic that ignores the chunk
    """
    return pessimistic_q(q).std(dim=-1).mean().item()  # (n, m, S) -> (m, S) -> (m,) -> ()


def twin_agreement(q: th.Tensor) -> float:
    """
    Fraction of states where every critic picks the same best candidate (``argmax_S Q_j``, the
    first of tied maxima). Healthy: well above chance ``1 / S``; near chance the critics rank on noise.

    :param q: values of every critic, shape ``(n_critics, m, S)``
    :return: in ``[0, 1]``
    """
    best = q.argmax(dim=-1)  # (n, m)
    return (best == best[:1]).all(dim=0).float().mean().item()


def critic_fit(q: th.Tensor, target: th.Tensor) -> dict[str, float]:
    """
    How well the critics fit their Bellman target (Eq. 3 with Eq. 4 / 8), from values the critic
    update already has: ``td_rmse = sqrt(mean_{j,b} (Q_j - y)^2)`` and ``twin_gap = mean_b |Q_1 - Q_2|``
    (the mean absolute difference of each critic from the first, averaged over the others).

    :param q: values of every critic on the batch's chunks, shape ``(n_critics, B)``
    :param target: ``y``, shape ``(B,)``
    :return: ``{"td_rmse", "twin_gap"}``, Q units (``twin_gap`` is 0 for one critic)
    """
    q, target = q.detach(), target.detach()
    td = (q - target.unsqueeze(0)).pow(2).mean().sqrt().item()
    gap = (q[1:] - q[:1]).abs().mean().item() if q.shape[0] > 1 else 0.0
    return {"td_rmse": td, "twin_gap": gap}


def _norm(grads: Sequence[th.Tensor]) -> float:
    return math.sqrt(sum(g.pow(2).sum().item() for g in grads))


# ---------------------------------------------------------------------------- model-level metrics
def _noise(shape: tuple[int, ...], generator: th.Generator, like: th.Tensor) -> th.Tensor:
    return th.randn(shape, generator=generator, dtype=like.dtype).to(like.device)


def planned_chunks(policy: UA2CPolicy, obs_history: th.Tensor, action_history: th.Tensor,
                   x0: th.Tensor) -> th.Tensor:
    """
    The chunk a replanning selects (as :meth:`~sb3_ua2c.policies.UA2CPolicy.plan_tensors`: candidates from the noise
    ``x0`` with ``flow_steps`` Euler steps, clipped, ``n_elite`` best by ``min_j Q_j``).

    :param obs_history: ``(m, ℓ, obs_dim)``
    :param action_history: ``(m, ℓ, action_dim)``
    :param x0: the candidates' noise, ``(m, S, k, action_dim)``
    :return: ``(m, k, action_dim)``
    """
    with th.no_grad():
        candidates, _ = policy.sample_candidates(obs_history, action_history, x0.shape[1], x0=x0)
        q = policy.critic(obs_history.flatten(1), candidates)  # (n, m, S)
        return select_chunk(candidates, pessimistic_q(q), policy.n_elite, policy.discrete_dims)


def plan_sensitivity(policy: UA2CPolicy, obs_history: th.Tensor, action_history: th.Tensor,
                     generator: th.Generator) -> dict[str, float]:
    """
    Does the plan follow the observations or the past actions? The planned first action of each
    history is compared, with the same candidate noise, to the one planned when its past actions
    (``sensitivity_past_actions``) or its observations (``sensitivity_observations``) are those of
    another history of the batch (the next one, cyclically). Continuous action dims only.

    Healthy: the observations move the plan more than the past actions; the reverse is the copycat
    problem of imitation from histories (de Haan et al., 2019; Wen et al., 2020).

    :param obs_history: ``(m, ℓ, obs_dim)``, ``m >= 2``
    :param action_history: ``(m, ℓ, action_dim)``
    :param generator: draws the candidates' noise (one draw for the three plans)
    :return: both mean shifts, action units
    """
    m = obs_history.shape[0]
    x0 = _noise((m, policy.n_candidates, policy.chunk_size, policy.action_dim), generator, obs_history)
    other = th.roll(th.arange(m, device=obs_history.device), 1)
    first = planned_chunks(policy, obs_history, action_history, x0)[:, 0]
    swapped_actions = planned_chunks(policy, obs_history, action_history[other], x0)[:, 0]
    swapped_obs = planned_chunks(policy, obs_history[other], action_history, x0)[:, 0]
    dims = policy.continuous_dims
    return {
        "sensitivity_past_actions": mean_abs_shift(swapped_actions, first, dims),
        "sensitivity_observations": mean_abs_shift(swapped_obs, first, dims),
    }


def action_correlations(policy: UA2CPolicy, data: ChunkReplaySamples, generator: th.Generator) -> dict[str, float]:
    """
    Correlation of the last past action ``a_{t-1}`` with the planned first action (``correlation_policy``)
    and with the logged ``a_t`` (``correlation_data``), continuous dims. Healthy: the policy's no higher
    than the data's; a policy at 0.99 against data at 0.9 holds its last action (copycat).

    :param data: a batch of the dataset (histories and logged chunks)
    :param generator: draws the candidates' noise
    """
    obs, act = data.observation_history, data.action_history
    x0 = _noise((obs.shape[0], policy.n_candidates, policy.chunk_size, policy.action_dim), generator, obs)
    planned = planned_chunks(policy, obs, act, x0)[:, 0]
    dims = policy.continuous_dims
    return {
        "correlation_policy": correlation(act[:, -1], planned, dims),
        "correlation_data": correlation(act[:, -1], data.chunks[:, 0], dims),
    }


def value_term_strength(model: UA2C, data: ChunkReplaySamples, generator: th.Generator,
                        shift: bool = True) -> dict[str, float]:
    """
    Does the value term move the actor? On one batch, the actor objective of the model's
    ``actor_type`` as training computes it (:func:`~sb3_ua2c.actors.actor_objective`; Eq. 2:
    masked flow term, x̂1 clipped before the critics; ``"one_step"``: the one-step policy's distillation
    and value terms), differentiated w.r.t. the network the value term trains (the velocity field, or
    the one-step policy): the gradient norms of the value term ``λ · Q term`` (``q_grad_norm``) and of
    the rest of the objective (``flow_grad_norm``: flow matching, or the distillation ``α · ||mu - flow||²``;
    with ``smooth_weight > 0`` the smoothness term too, as the optimizer sees it),
    their ratio ``q_grad_ratio``, and ``x_hat_shift``: the mean ``|Δ|`` (action units) of the valued
    chunks (x̂1, or ``mu(h, z)``) after one step of the value term alone, scaled as Adam scales it when
    its second moment is this batch's squared gradient of both terms (each parameter moves by
    ``lr · g_Q / sqrt(g_flow² + g_Q²)``, at most ``lr``).

    Healthy: a ratio of 0.1 .. 1 (far below, the actor is behaviour cloning) and a shift that is a
    visible fraction of the action range.

    :param model: the model (its actors, critics, ``q_weight`` and actor learning rate)
    :param data: a batch with ``chunk_mask``
    :param generator: draws the objective's noise (``x0``, ``tau``, and ``z`` / the dropout when used)
    :param shift: compute ``x_hat_shift`` (skipped during training)
    """
    policy = model.policy
    net = policy.value_trained_actor()
    params = [p for p in net.parameters() if p.requires_grad]
    start = generator.get_state()

    def objective(q_weight: float) -> ActorObjective:
        generator.set_state(start)  # the same noise for every evaluation
        return actor_objective(policy.actor_type, policy.actor_inputs(), data, model.actor_weights(q_weight), generator)

    imitation, total = objective(0.0), objective(model.q_weight)
    g_flow = th.autograd.grad(imitation.loss, params)
    g_q = [a - b for a, b in zip(th.autograd.grad(total.loss, params), g_flow, strict=True)]
    q_norm, flow_norm = _norm(g_q), _norm(g_flow)
    out = {"q_grad_norm": q_norm, "flow_grad_norm": flow_norm,
           "q_grad_ratio": q_norm / flow_norm if flow_norm > 0 else math.nan}
    if shift:
        lr = model.actor.optimizer.param_groups[0]["lr"]
        saved = [p.detach().clone() for p in params]
        with th.no_grad():
            for p, gq, gf in zip(params, g_q, g_flow, strict=True):
                p.sub_(lr * gq / (gf.pow(2) + gq.pow(2)).sqrt().clamp_min(1e-12))
            try:
                out["x_hat_shift"] = (objective(model.q_weight).chunks - total.chunks).abs().mean().item()
            finally:
                for p, value in zip(params, saved, strict=True):
                    p.copy_(value)
    return out


def candidate_ranking(policy: UA2CPolicy, obs_history: th.Tensor, action_history: th.Tensor,
                      generator: th.Generator) -> dict[str, float]:
    """
    :func:`candidate_q_std` and :func:`twin_agreement` of the ``n_candidates`` candidates a replanning
    samples (``flow_steps``, clipped) at each history, valued by the critics.

    :param obs_history: ``(m, ℓ, obs_dim)``
    :param action_history: ``(m, ℓ, action_dim)``
    :param generator: draws the candidates' noise
    """
    x0 = _noise((obs_history.shape[0], policy.n_candidates, policy.chunk_size, policy.action_dim),
                generator, obs_history)
    with th.no_grad():
        candidates, _ = policy.sample_candidates(obs_history, action_history, policy.n_candidates, x0=x0)
        q = policy.critic(obs_history.flatten(1), candidates)  # (n, m, S)
    return {"candidate_q_std": candidate_q_std(q), "twin_agreement": twin_agreement(q)}


def critic_fit_on_batch(model: UA2C, data: ChunkReplaySamples) -> dict[str, float]:
    """
    :func:`critic_fit` of the critics on a batch, against the target the critic update computes
    (``UA2C._next_values`` and :func:`~sb3_ua2c.chunking.chunk_target`; its candidates use the global
    random stream, as in training).
    """
    with th.no_grad():
        next_value = model._next_values(data.next_observation_history, data.next_action_history)
        target = chunk_target(data.rewards, data.horizons, data.bootstrap, next_value, model.gamma)
        q = model.critic(data.observation_history.flatten(1), data.chunks.unsqueeze(1)).squeeze(2)  # (n, B)
    return critic_fit(q, target)


def policy_gap(model: UA2C, obs_history: th.Tensor, action_history: th.Tensor,
               generator: th.Generator) -> dict[str, float]:
    """
    Does the bootstrap of Eq. 4 / 8 value the policy that acts? ``acting_value``: ``min_j Q̄_j`` (target
    critics) of the chunk a replanning selects (``n_candidates`` x ``flow_steps``, ``n_elite`` best);
    ``bootstrap_value``: the target's ``max`` over ``n_target_candidates`` chunks of ``target_flow_steps``
    Euler steps (:func:`~sb3_ua2c.chunking.bootstrap_value`), both on the same histories and target
    critics; ``policy_gap`` their mean difference; ``spread_ratio``: the candidates' standard deviation
    (over samples, mean over positions and dims) at ``target_flow_steps`` over the one at ``flow_steps``,
    from the same noise. Healthy: a gap near 0 (the targets value the acting policy) and a ratio near 1.
    """
    policy = model.policy
    s, k, a = policy.n_candidates, policy.chunk_size, policy.action_dim
    x0 = _noise((obs_history.shape[0], s, k, a), generator, obs_history)
    obs_flat = obs_history.flatten(1)
    with th.no_grad():
        chunk = planned_chunks(policy, obs_history, action_history, x0)
        acting = pessimistic_q(model.critic_target(obs_flat, chunk.unsqueeze(1)))[:, 0]  # (m,)
        q_count = min(model.n_target_candidates, s)
        target_samples = policy.sample_chunks(obs_history, action_history, s, model.target_flow_steps, x0=x0)
        acting_samples = policy.sample_chunks(obs_history, action_history, s, policy.flow_steps, x0=x0)
        target_samples, acting_samples = target_samples.clamp(-1.0, 1.0), acting_samples.clamp(-1.0, 1.0)
        boot = bootstrap_value(model.critic_target(obs_flat, target_samples[:, :q_count]))  # (m,)
        spread = target_samples.std(dim=1).mean() / acting_samples.std(dim=1).mean().clamp_min(1e-12)
    return {"acting_value": acting.mean().item(), "bootstrap_value": boot.mean().item(),
            "policy_gap": (acting - boot).mean().item(), "spread_ratio": spread.item()}


def training_diagnostics(model: UA2C, data: ChunkReplaySamples) -> dict[str, float]:
    """
    The cheap subset logged during training every :data:`DIAGNOSTICS_INTERVAL` updates: ``q_grad_ratio``
    (:func:`value_term_strength` without the shift), ``candidate_q_std`` and ``twin_agreement``
    (:func:`candidate_ranking` on the first :data:`TRAINING_HISTORIES` histories of the batch). The noise
    comes from a generator seeded by the update count: the training's random streams do not move.
    """
    generator = th.Generator().manual_seed(int(model._n_updates))
    strength = value_term_strength(model, data, generator, shift=False)
    m = TRAINING_HISTORIES
    ranking = candidate_ranking(model.policy, data.observation_history[:m], data.action_history[:m], generator)
    return {"q_grad_ratio": strength["q_grad_ratio"], **ranking}


def training_stats(model: UA2C, data: ChunkReplaySamples, q: th.Tensor, target: th.Tensor) -> dict[str, float]:
    """
    What ``UA2C`` logs at an update: :func:`critic_fit` of the critic update's values, and every
    :data:`DIAGNOSTICS_INTERVAL` updates :func:`training_diagnostics` as well.

    :param q: the critics' values on the batch, ``(n_critics, B)``
    :param target: their target, ``(B,)``
    """
    stats = critic_fit(q, target)
    if model._n_updates % DIAGNOSTICS_INTERVAL == 0:
        stats.update(training_diagnostics(model, data))
    return stats


def diagnose(model: UA2C, data: ChunkReplaySamples, seed: int = 0) -> dict[str, float]:
    """
    Every metric of :data:`METRICS` on one batch of histories (each metric's function says what it
    measures and what is healthy).

    :param model: the model
    :param data: a batch of the dataset (:func:`dataset_batch`), at least 2 histories
    :param seed: seeds the candidates' noise and the targets' candidates
    :return: ``{metric: value}`` in the order of :data:`METRICS`
    """
    if data.chunks.shape[0] < 2:
        raise ValueError(f"diagnose needs at least 2 histories, got {data.chunks.shape[0]}")
    model.policy.set_training_mode(False)
    generator = th.Generator().manual_seed(seed)
    obs, act = data.observation_history, data.action_history
    out = {**plan_sensitivity(model.policy, obs, act, generator),
           **action_correlations(model.policy, data, generator),
           **value_term_strength(model, data, generator),
           **candidate_ranking(model.policy, obs, act, generator),
           **policy_gap(model, obs, act, generator)}
    th.manual_seed(seed)  # the targets' candidates, as in training
    out.update(critic_fit_on_batch(model, data))
    return {name: out[name] for name in METRICS}


# ---------------------------------------------------------------------------- loading and command
def dataset_batch(model: UA2C, episodes: Any, n_histories: int, seed: int = 0) -> ChunkReplaySamples:
    """
    ``n_histories`` histories drawn uniformly (with replacement) from the k-step windows of the
    episodes (env action units, rescaled as :meth:`~sb3_ua2c.offline_training.OfflineTraining.add_offline_episodes` does), with their
    logged chunks, rewards and next histories.
    """
    import numpy as np

    from sb3_ua2c.checks import check_int

    check_int("n_histories", n_histories, low=2)
    buffer = model._make_replay_buffer(model.chunk_size + model.history_len)
    if buffer.add_offline_episodes(model._normalized_episodes(episodes, actions_normalized=False)) == 0:
        raise ValueError("DATASET holds no steps")
    state = np.random.get_state()  # noqa: NPY002 - the buffer samples with NumPy's global RNG
    np.random.seed(seed)  # noqa: NPY002
    try:
        return buffer.sample(n_histories)
    finally:
        np.random.set_state(state)  # noqa: NPY002


def format_report(values: dict[str, float]) -> str:
    """The metrics as a text table: name, value, what it measures, a healthy value."""
    lines = [f"{'metric':<25} {'value':>9}  meaning (healthy)"]
    for name, (meaning, healthy) in METRICS.items():
        lines.append(f"{name:<25} {values[name]:>9.4f}  {meaning} ({healthy})")
    return "\n".join(lines)
