"""Pure maths of chunks, one typed function per equation of the paper: the per-position entropies
``H_u`` and the executed length ``L_t`` of Eq. 7 (and the δ that gives a target mean ``L_t``), the
selection of the executed chunk, the chunk targets of Eq. 4 / Eq. 8 and the critic loss of Eq. 3.
The execution state machine that applies them step by step is :mod:`sb3_ua2c.execution`.

Conventions: a set of sampled candidate chunks has shape ``(*batch, S, k, action_dim)``; per-position
statistics have shape ``(*batch, k)``; actions live in SB3's normalised action space ``[-1, 1]``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch as th

#: variance floor inside the Gaussian entropy, so that identical samples give a finite entropy
ENTROPY_EPS = 1e-6


def continuous_dims(action_dim: int, discrete_dims: Mapping[int, int] | None) -> list[int]:
    """The action dims that are not categorical, in order (``discrete_dims`` as
    :func:`~sb3_ua2c.config.normalize_discrete_dims` returns)."""
    return [d for d in range(action_dim) if d not in (discrete_dims or {})]


def categorize(actions: th.Tensor, n_categories: int) -> th.Tensor:
    """
    Map normalised actions to category indices by ``n_categories`` equal-width bins over [-1, 1].

    :param actions: tensor of any shape, values in (or clipped to) [-1, 1]
    :param n_categories: number of categories ``n``
    :return: long tensor of the same shape with values in ``{0, ..., n - 1}``
    """
    scaled = (actions.clamp(-1.0, 1.0) + 1.0) * (0.5 * n_categories)
    return scaled.floor().long().clamp_(0, n_categories - 1)


def gaussian_entropy(samples: th.Tensor, eps: float = ENTROPY_EPS) -> th.Tensor:
    """
    Entropy of a Gaussian fitted to samples along dim ``-3`` (the candidate dim):
    ``0.5 * log(2 pi e (sigma_hat^2 + eps))`` with the unbiased sample variance (0 for one sample).

    :param samples: candidate chunks (unclipped), shape ``(*batch, S, k, d)``
    :param eps: variance floor
    :return: per-position, per-dimension entropy, shape ``(*batch, k, d)``
    """
    n = samples.shape[-3]
    var = samples.var(dim=-3, correction=1) if n > 1 else th.zeros_like(samples.select(-3, 0))
    return 0.5 * th.log(2.0 * math.pi * math.e * (var + eps))


def categorical_entropy(categories: th.Tensor, n_categories: int) -> th.Tensor:
    """
    Entropy of the empirical distribution of category indices along dim ``-2`` (the candidate dim).

    :param categories: long tensor of shape ``(*batch, S, k)``
    :param n_categories: number of categories
    :return: ``-sum_c p_c log p_c`` (with ``0 log 0 = 0``), shape ``(*batch, k)``
    """
    # (*batch, S, k) -> (*batch, S, k, n) -> frequencies (*batch, k, n)
    p = th.nn.functional.one_hot(categories, n_categories).to(th.float32).mean(dim=-3)
    return -(p * th.log(p.clamp_min(1e-30))).sum(dim=-1)


def chunk_entropy(
    samples: th.Tensor,
    discrete_dims: Mapping[int, int] | None = None,
    eps: float = ENTROPY_EPS,
    *,
    discrete: bool,
) -> th.Tensor:
    """
    Per-position entropy ``H_u`` of the sampled actions (Eq. 7), over the S candidates.

    Continuous dims use the Gaussian entropy of the unclipped samples, categorical dims the entropy
    of the empirical category frequencies. The action is treated as a factorised distribution, so
    ``H_u`` is the sum over action dims of the per-dim entropies; ``discrete=False`` leaves the
    categorical dims out (``H_u`` of the continuous dims alone).

    :param samples: candidate chunks, shape ``(*batch, S, k, action_dim)``
    :param discrete_dims: ``{dim: n_categories}`` for categorical dims (see :func:`~sb3_ua2c.config.normalize_discrete_dims`)
    :param eps: variance floor of the Gaussian entropy
    :param discrete: add the entropies of the categorical dims (the policy's ``discrete_entropy``)
    :return: ``H_u`` for ``u = 1..k``, shape ``(*batch, k)``
    """
    discrete_dims = dict(discrete_dims or {})
    action_dim = samples.shape[-1]
    continuous = continuous_dims(action_dim, discrete_dims)
    total = th.zeros(samples.shape[:-3] + samples.shape[-2:-1], dtype=samples.dtype, device=samples.device)
    if continuous:
        cont = samples if len(continuous) == action_dim else samples[..., continuous]
        total = total + gaussian_entropy(cont, eps).sum(dim=-1)
    for dim, n in discrete_dims.items() if discrete else ():
        total = total + categorical_entropy(categorize(samples[..., dim], n), n).to(samples.dtype)
    return total


def select_chunk(
    candidates: th.Tensor,
    values: th.Tensor,
    n_elite: int,
    discrete_dims: Mapping[int, int] | None = None,
) -> th.Tensor:
    """
    The chunk a replanning executes, from its S candidates and their values ``min_j Q_j`` (:func:`pessimistic_q`).

    ``n_elite = 1`` keeps the candidate of highest value (best-of-S). ``n_elite = m > 1`` averages the
    continuous action dims of the ``m`` highest-valued candidates position by position (an elite mean,
    as in the cross-entropy method): the value still chooses which samples count, and the flow's
    sampling noise, independent between candidates, shrinks by about ``sqrt(m)`` inside the chunk.
    Categorical dims are never averaged: they keep the best candidate's value.

    :param candidates: clipped candidate chunks, shape ``(m, S, k, action_dim)``
    :param values: their values, shape ``(m, S)``
    :param n_elite: number of best candidates averaged, in ``[1, S]`` (the policy's ``n_elite``)
    :param discrete_dims: ``{dim: n_categories}`` of categorical dims
    :return: selected chunks, shape ``(m, k, action_dim)``
    """
    m, s = values.shape
    if not 1 <= n_elite <= s:
        raise ValueError(f"n_elite must be in [1, {s}] (the number of candidates), got {n_elite}")
    rows = th.arange(m, device=candidates.device)
    if n_elite == 1:
        return candidates[rows, values.argmax(dim=1)]
    elite = values.topk(n_elite, dim=1).indices  # (m, n_elite), best first
    chunks = candidates[rows.unsqueeze(1), elite].mean(dim=1)  # (m, n_elite, k, A) -> (m, k, A)
    for dim in discrete_dims or {}:
        chunks[..., dim] = candidates[rows, elite[:, 0], :, dim]
    return chunks


#: How a replanning turns its S candidates into the executed chunk (the policy's ``selection``):
#: ``"elite"`` the elite mean of the ``n_elite`` best by ``min_j Q_j`` (:func:`select_chunk`; ``n_elite=1`` the
#: best candidate, the paper's), ``"uncertainty"`` a mean weighted by the critics' ranking as far as it exceeds
#: their disagreement (:func:`uncertainty_weights`), and three rules that do not read the critics: ``"mean"``
#: of all candidates, one ``"sample"`` (the first candidate) and ``"zero_noise"``, the flow integrated from
#: ``x_0 = 0``. Whatever the selection, ``L_t`` follows from the S candidates' entropies.
SELECTIONS = ("elite", "uncertainty", "mean", "sample", "zero_noise")
#: the selections that rank candidates by the critics (the others skip the critic call when acting)
CRITIC_SELECTIONS = ("elite", "uncertainty")


def uncertainty_weights(q_values: th.Tensor) -> th.Tensor:
    """
    Weights of the uncertainty-aware selection (not in the paper): ``w = softmax(mean_j Q_j / tau)`` over the S
    candidates of a history, with the temperature ``tau`` the critics' own disagreement, the mean over the
    candidates of ``max_j Q_j - min_j Q_j`` (``|Q_1 - Q_2|`` for twin critics). Where the critics' ranking
    spreads the candidates by less than they disagree, the weights stay near uniform (the mean of the
    candidates); where it spreads them by more, the weights concentrate on the best (towards the elite).

    :param q_values: the critics' values of the candidates, shape ``(n_critics, m, S)``, ``n_critics >= 2``
    :return: weights, shape ``(m, S)``, each row summing to 1
    """
    if q_values.shape[0] < 2:
        raise ValueError(f"the uncertainty-aware selection needs at least 2 critics, got n_critics={q_values.shape[0]}")
    spread = q_values.max(dim=0).values - q_values.min(dim=0).values  # (m, S)
    tau = spread.mean(dim=-1, keepdim=True).clamp_min(1e-6)  # (m, 1)
    return th.softmax(q_values.mean(dim=0) / tau, dim=-1)  # (m, S)


def weighted_chunk(
    candidates: th.Tensor, weights: th.Tensor, discrete_dims: Mapping[int, int] | None = None
) -> th.Tensor:
    """
    ``sum_i w_i * candidate_i`` position by position; categorical dims are never averaged: they keep the
    candidate of the largest weight (the first of equal ones).

    :param candidates: clipped candidate chunks, shape ``(m, S, k, action_dim)``
    :param weights: ``(m, S)``, rows summing to 1
    :param discrete_dims: ``{dim: n_categories}`` of categorical dims
    :return: chunks, shape ``(m, k, action_dim)``
    """
    chunks = (weights[:, :, None, None] * candidates).sum(dim=1)  # (m, S, k, A) -> (m, k, A)
    if discrete_dims:
        rows = th.arange(candidates.shape[0], device=candidates.device)
        lead = candidates[rows, weights.argmax(dim=1)]  # (m, k, A)
        for dim in discrete_dims:
            chunks[..., dim] = lead[..., dim]
    return chunks


def select_candidates(
    selection: str,
    candidates: th.Tensor,
    q_values: th.Tensor | None,
    n_elite: int,
    discrete_dims: Mapping[int, int] | None = None,
) -> th.Tensor:
    """
    The executed chunk of a replanning by ``selection`` (one of :data:`SELECTIONS` but ``"zero_noise"``,
    which is a chunk of its own: :meth:`~sb3_ua2c.policies.UA2CPolicy.plan_tensors`).

    :param selection: ``"elite"``, ``"uncertainty"``, ``"mean"`` or ``"sample"``
    :param candidates: clipped candidate chunks, shape ``(m, S, k, action_dim)``
    :param q_values: the critics' values ``(n_critics, m, S)`` (``None`` for the selections that do not read them)
    :param n_elite: candidates of the elite mean
    :param discrete_dims: ``{dim: n_categories}`` of categorical dims
    :return: ``(m, k, action_dim)``
    """
    if selection in CRITIC_SELECTIONS and q_values is None:
        raise ValueError(f"selection={selection!r} ranks the candidates by the critics: q_values are needed")
    if selection == "elite":
        return select_chunk(candidates, pessimistic_q(q_values), n_elite, discrete_dims)
    if selection == "uncertainty":
        return weighted_chunk(candidates, uncertainty_weights(q_values), discrete_dims)
    if selection == "mean":
        m, s = candidates.shape[:2]
        return weighted_chunk(candidates, candidates.new_full((m, s), 1.0 / s), discrete_dims)
    if selection == "sample":
        return candidates[:, 0]
    raise ValueError(f"selection must be one of {list(SELECTIONS[:-1])} here, got {selection!r}")


def executable_prefix_length(entropy: th.Tensor, threshold: float | th.Tensor) -> th.Tensor:
    """
    Executable prefix length of Eq. 7: the largest ``u`` such that ``H_1..H_u <= delta``, at least 1.

    ``threshold = inf`` executes the whole chunk (fixed chunking); a NaN entropy counts as unreliable.

    :param entropy: per-position entropy, shape ``(*batch, k)``
    :param threshold: entropy threshold ``delta``, a number or a tensor broadcastable to ``(*batch, 1)``
    :return: long tensor ``L_t`` in ``[1, k]``, shape ``(*batch,)``
    """
    ok = (entropy <= threshold).long()
    return th.cumprod(ok, dim=-1).sum(dim=-1).clamp_(min=1)


def entropy_growth_length(entropy: th.Tensor, growth: float) -> th.Tensor:
    """
    Executable prefix length of the growth rule (``execution_rule="growth"``, not in the paper): the
    largest ``u`` such that ``H_{u'} - H_1 <= c`` for every ``u' <= u``. The rule compares each
    position with the plan's own first one, so ``H_1`` gates nothing (``L_t >= 1`` always) and a
    shift of every ``H_u`` by one constant (rescaled action bounds, a constant action dimension)
    leaves ``L_t`` unchanged. In standard deviations: ``sigma_u / sigma_1 <= e^c`` for one action dim.

    :param entropy: per-position entropy ``H_u``, shape ``(*batch, k)``
    :param growth: ``c``, nats above ``H_1`` (``>= 0``)
    :return: long tensor ``L_t`` in ``[1, k]``, shape ``(*batch,)``
    """
    return executable_prefix_length(entropy - entropy[..., :1], growth)  # (*batch, k) - (*batch, 1)


def quantile_entropy_thresholds(entropy: th.Tensor, quantile: float) -> th.Tensor:
    """
    Per-position thresholds ``delta_u`` of the calibrated rule (``execution_rule="quantile"``, not in
    the paper): the ``q``-quantile over ``n`` histories of ``H_u`` at each position ``u``. Eq. 7 with
    these thresholds executes position ``u`` where the plan is at least as sure there as a fraction
    ``q`` of the calibration histories (linear interpolation between order statistics, as
    ``torch.quantile``). Shifting every ``H_u`` by one constant shifts every ``delta_u`` by it.

    :param entropy: ``H_u`` of the calibration histories, shape ``(n, k)``; NaN rows are ignored
    :param quantile: ``q`` in ``[0, 1]``
    :return: ``delta_u``, shape ``(k,)``
    """
    return th.nanquantile(entropy, quantile, dim=0)  # (n, k) -> (k,)


def default_target_plan_length(chunk_size: int) -> float:
    """``target_plan_length`` of ``entropy_threshold="auto"`` when not given: ``(k + 1) / 2``, halfway between
    one action per plan (the one-step baseline) and the whole chunk (fixed execution)."""
    return (chunk_size + 1) / 2


def auto_entropy_threshold(entropy: th.Tensor, target: float) -> th.Tensor:
    """
    The δ of Eq. 7 under which the mean ``L_t`` over ``n`` replannings reaches ``target``
    (``entropy_threshold="auto"``).

    With the running maxima ``M_u = max(H_1..H_u)``, ``L_t(δ) = max(1, #{u : M_u <= δ}) = 1 + #{u >= 2 :
    M_u <= δ}``, so ``n * (mean L_t(δ) - 1)`` counts the pooled ``M_u``, ``u >= 2``, that are ``<= δ``. The
    ``c``-th smallest of them, ``c = ceil(n (target - 1))``, is the smallest δ whose mean ``L_t`` is at
    least ``target``: exactly ``target`` when ``n (target - 1)`` is an integer and no two maxima tie, else
    the next mean above it. ``target = 1`` gives ``-inf`` (one action per plan). A NaN entropy counts as
    unreliable (``+inf``), as in :func:`executable_prefix_length`.

    :param entropy: per-position entropies ``H_u`` of ``n >= 1`` replannings, shape ``(*batch, n, k)``
        (a leading batch dim gives one δ per group, e.g. ``(m, 1, k)`` one per row)
    :param target: target mean ``L_t`` in ``[1, k]``
    :return: δ, shape ``(*batch,)``
    """
    n, k = entropy.shape[-2:]
    count = math.ceil(n * (target - 1.0) - 1e-9)  # the maxima that must be <= δ
    if count <= 0:
        return th.full(entropy.shape[:-2], -math.inf, dtype=entropy.dtype, device=entropy.device)
    maxima = th.cummax(entropy.nan_to_num(nan=math.inf), dim=-1).values[..., 1:]  # (*batch, n, k-1)
    return maxima.flatten(-2).kthvalue(min(count, n * (k - 1)), dim=-1).values  # (*batch, n*(k-1)) -> (*batch)


def commit_through_switch(
    lengths: th.Tensor, chunks: th.Tensor, discrete_dims: Mapping[int, int] | None
) -> th.Tensor:
    """
    Extend ``L_t`` (Eq. 7) through the first switch of a categorical action inside the selected chunk
    (not in the paper; ``UA2C(commit_discrete=True)``).

    A chunk ``[keep, keep, keep, change, keep]`` of a lane change switches at ``u = 3``; the prefix
    then ends at ``L_t >= 4``, so the change is executed before the next replanning. Without it,
    replanning more often than the chunk schedules its lane change can postpone the change forever
    (every new plan puts it a few steps ahead again). ``L_t`` never shrinks; a chunk with no switch
    keeps its ``L_t``; ``k = 1`` and ``L_t = k`` are unchanged.

    :param lengths: ``L_t`` of Eq. 7, long tensor of shape ``(m,)``
    :param chunks: selected chunks, shape ``(m, k, action_dim)``
    :param discrete_dims: ``{dim: n_categories}`` of categorical dims
    :return: the committed lengths, shape ``(m,)``
    """
    k = chunks.shape[-2]
    out = lengths
    u = th.arange(1, k, device=chunks.device)  # switch positions 1..k-1 (none for k = 1)
    for dim, n in (discrete_dims or {}).items() if k > 1 else ():
        cats = categorize(chunks[..., dim], n)  # (m, k)
        switch = cats[:, 1:] != cats[:, :-1]  # (m, k-1): the category changes at u
        first = th.where(switch, u, k).amin(dim=-1)  # (m,), k = no switch
        out = th.maximum(out, th.where(first < k, first + 1, out))
    return out


def discounted_chunk_return(rewards: th.Tensor, horizon: th.Tensor, gamma: float) -> th.Tensor:
    """
    ``sum_{u < L} gamma^u r_{t+u}`` of Eq. 4 (``L = k``) and Eq. 8 (``L = L_t``).

    :param rewards: rewards of the window, shape ``(batch, k)``; entries at ``u >= L`` are ignored
    :param horizon: per-sample horizon ``L``, shape ``(batch,)``
    :param gamma: discount factor
    :return: discounted returns, shape ``(batch,)``
    """
    k = rewards.shape[-1]
    u = th.arange(k, device=rewards.device)
    discounts = th.pow(th.as_tensor(gamma, dtype=rewards.dtype, device=rewards.device), u.to(rewards.dtype))
    mask = u.unsqueeze(0) < horizon.unsqueeze(-1)  # (batch, k)
    return (rewards * discounts * mask).sum(dim=-1)


def pessimistic_q(q_values: th.Tensor) -> th.Tensor:
    """
    Pessimistic value ``min_j Q_j(h, a)`` over the critic ensemble (clipped double-Q): the value that
    ranks the replanning candidates of Eq. 7, scores the actor's chunk in Eq. 2, and, over the
    target critics, enters the bootstrap of Eq. 4 / Eq. 8 (:func:`bootstrap_value`).

    :param q_values: one value per critic, shape ``(n_critics, *batch)``, e.g. ``(n_critics, B, C)``
        from the chunk critic on ``C`` chunks per history
    :return: minimum over the critics, shape ``(*batch,)``
    """
    return q_values.min(dim=0).values  # (n_critics, *batch) -> (*batch)


def bootstrap_value(q_candidates: th.Tensor) -> th.Tensor:
    """
    Bootstrap value of Eq. 4 / Eq. 8: ``max_q min_j Q_target_j(h', a^(q))``, the best of ``Q`` chunks
    sampled from the policy at the next history ``h'``, each valued pessimistically over the target
    critics.

    :param q_candidates: target-critic values of the candidates, shape ``(n_critics, B, Q)``
    :return: ``V(h')``, shape ``(B,)``
    """
    return pessimistic_q(q_candidates).max(dim=1).values  # (n, B, Q) -> (B, Q) -> (B,)


def chunk_target(
    rewards: th.Tensor,
    horizon: th.Tensor,
    bootstrap_mask: th.Tensor,
    next_value: th.Tensor,
    gamma: float,
) -> th.Tensor:
    """
    Chunk-level Bellman target of Eq. 4 / Eq. 8, one code path for both:
    ``y = sum_{u < L} gamma^u r_{t+u} + m * gamma^L * V(h_{t+L})``.

    An episode that terminates inside the window has ``L`` cut at the terminal step and ``m = 0``;
    a time-limit truncation keeps ``m = 1`` (bootstrap from the last observation).

    :param rewards: window rewards, shape ``(batch, k)``
    :param horizon: ``L`` per sample (``k`` for full offline windows, ``L_t`` for online plans), ``(batch,)``
    :param bootstrap_mask: ``m`` in {0, 1}, shape ``(batch,)``
    :param next_value: ``max_q min_j Q_target_j(h_{t+L}, a^(q))`` (:func:`bootstrap_value`), shape ``(batch,)``
    :param gamma: discount factor
    :return: targets ``y``, shape ``(batch,)``
    """
    discount = th.pow(
        th.as_tensor(gamma, dtype=rewards.dtype, device=rewards.device), horizon.to(rewards.dtype)
    )
    return (
        discounted_chunk_return(rewards, horizon, gamma)
        + bootstrap_mask.to(rewards.dtype) * discount * next_value
    )


def chunk_critic_loss(q_values: th.Tensor, target: th.Tensor) -> th.Tensor:
    """
    Chunk-level Bellman regression of Eq. 3: ``sum_j E[(Q_phi_j(o-history, a_{t:t+k-1}) - y_t)^2]``.

    :param q_values: predictions of every critic, shape ``(n_critics, batch)``
    :param target: ``y_t`` (no gradient), shape ``(batch,)``
    :return: scalar loss
    """
    error = (q_values - target.detach().unsqueeze(0)).pow(2)  # (n, batch)
    return error.flatten(1).mean(dim=1).sum()
