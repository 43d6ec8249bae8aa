"""In-sample chunk values and advantage-weighted extraction (not in the UA2C paper): the maths of
``critic_target="in_sample"``, ``actor_extraction="awr"`` and ``exploration="softmax"``.

Eq. 4 bootstraps from the best of chunks that the actor samples at the next history: values of actions
the data may never show. An in-sample value, as in IQL (Kostrikov et al., ICLR 2022) and its flow-policy
forms IFQL (Park et al., 2025) and SHARSA (Park et al., 2025), queries only the data's own chunks:

- ``V(h_t)`` is fitted by expectile regression to the target critics' value of the data's chunk,
  ``min_j Q̄_j(h_t, a_{t:t+k})`` (:func:`expectile_loss`);
- ``Q(h_t, a_{t:t+L})`` regresses on ``sum_{u<L} gamma^u r_{t+u} + gamma^L V(h_{t+L})`` (the one chunk target
  of Eq. 4 / 8, :func:`~sb3_ua2c.chunking.chunk_target`, with ``V`` in place of the candidates' max);
- the actor weights the flow-matching error of each data chunk by ``min(exp(beta A), w_max)`` with
  ``A = Q - V`` (advantage-weighted regression, :func:`advantage_weights`), and acts by the best of S
  candidates under ``Q`` as before;
- while learning online, the executed candidate is drawn with probability ``∝ exp(Q / T)``
  (:func:`softmax_candidate`), so exploration does not collapse to the elite mean, which
  ``predict(deterministic=True)`` keeps.
"""

from __future__ import annotations

import torch as th


def expectile_loss(q: th.Tensor, v: th.Tensor, expectile: float) -> th.Tensor:
    """
    IQL's value loss (Kostrikov et al., 2022, Eq. 5) on chunks: ``E[|tau - 1(u < 0)| u^2]``, ``u = Q - V``.

    ``tau = 0.5`` is the mean squared error; ``tau -> 1`` makes ``V(h)`` approach the largest value of the
    data's chunks at ``h`` (an in-sample maximum).

    :param q: ``min_j Q̄_j(h, a)`` of the data's chunks (no gradient), shape ``(B,)``
    :param v: ``V(h)``, shape ``(B,)``
    :param expectile: ``tau`` in ``(0, 1)``
    :return: scalar loss
    """
    u = q.detach() - v  # (B,)
    weight = th.where(u < 0, 1.0 - expectile, expectile)  # (B,)
    return (weight * u.pow(2)).mean()


def advantage_weights(q: th.Tensor, v: th.Tensor, temperature: float, max_weight: float) -> th.Tensor:
    """
    Advantage weights of AWR / IQL's policy extraction: ``min(exp(beta (Q - V)), w_max)``, no gradient.

    :param q: ``min_j Q_j(h, a)`` of the data's chunks, shape ``(B,)``
    :param v: ``V(h)``, shape ``(B,)``
    :param temperature: ``beta >= 0`` (0: every weight 1, plain flow matching)
    :param max_weight: ``w_max > 0``
    :return: weights, shape ``(B,)``
    """
    advantage = (q - v).detach()  # (B,)
    return th.exp(temperature * advantage).clamp(max=max_weight)


def softmax_candidate(values: th.Tensor, temperature: float, generator: th.Generator | None = None) -> th.Tensor:
    """
    One candidate per row drawn with probability ``∝ exp(Q / T)`` (IDQL's resampling, Hansen-Estruch et
    al., 2023): ``T -> 0`` is the best candidate, ``T -> inf`` a uniform draw.

    :param values: ``min_j Q_j`` of the S candidates, shape ``(m, S)``
    :param temperature: ``T > 0``, in the critics' units (reward)
    :param generator: optional random generator
    :return: long tensor of indices in ``[0, S)``, shape ``(m,)``
    """
    logits = (values - values.amax(dim=1, keepdim=True)) / temperature  # (m, S), max 0
    return th.multinomial(logits.exp(), 1, generator=generator).squeeze(1)  # (m, S) -> (m,)


__all__ = ["advantage_weights", "expectile_loss", "softmax_candidate"]
