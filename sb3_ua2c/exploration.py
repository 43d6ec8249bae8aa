"""Which candidate a training rollout executes, by name: UA2C's ``exploration`` picks a class of
:data:`EXPLORATIONS` and ``exploration_kwargs`` holds its own arguments, whose defaults are in its
signature (:mod:`sb3_ua2c.registry`). It acts in ``learn()``'s rollouts only: ``predict`` and
``evaluate_policy`` always act by the policy's ``selection`` (:func:`~sb3_ua2c.chunking.select_candidates`), and the
executed length ``L_t`` follows from the candidates' entropies as before, whichever candidate runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import torch as th

from sb3_ua2c.checks import check_number
from sb3_ua2c.chunking import pessimistic_q, select_chunk, uncertainty_weights
from sb3_ua2c.in_sample_maths import softmax_candidate


class ChunkSelector(Protocol):
    """The selection of a replanning's executed chunk (``UA2CPolicy.plan_tensors(..., selector=)``)."""

    def select(
        self, candidates: th.Tensor, q_values: th.Tensor, n_elite: int, discrete_dims: Mapping[int, int]
    ) -> th.Tensor:
        """``(m, S, k, A)`` clipped candidates and the critics' ``(n_critics, m, S)`` values -> ``(m, k, A)``."""


class PlanExploration:
    """Rollouts act as ``predict``: by the policy's ``selection`` (``follows_policy``; :meth:`select` is the elite
    mean of the ``n_elite`` best candidates, :func:`~sb3_ua2c.chunking.select_chunk`, for a caller that asks it
    directly). No own arguments."""

    #: ``UA2CPolicy.plan_tensors`` selects by the policy's own ``selection`` under this rule
    follows_policy = True

    def select(
        self, candidates: th.Tensor, q_values: th.Tensor, n_elite: int, discrete_dims: Mapping[int, int]
    ) -> th.Tensor:
        """:func:`~sb3_ua2c.chunking.select_chunk` (see :class:`ChunkSelector`)."""
        return select_chunk(candidates, pessimistic_q(q_values), n_elite, discrete_dims)


class SoftmaxExploration:
    """
    One candidate drawn with probability ``∝ exp(min_j Q_j / T)`` (IDQL's resampling, Hansen-Estruch et
    al., 2023; :func:`~sb3_ua2c.in_sample_maths.softmax_candidate`), from torch's global random stream so that
    seeded runs reproduce. Not in the paper: the elite mean barely explores, a draw among candidates
    of the actor's support explores without leaving it.

    :param temperature: ``T > 0`` in the critics' units (reward): ``T -> 0`` the best candidate,
        ``T -> inf`` a uniform draw
    """

    def __init__(self, temperature: float = 1.0) -> None:
        check_number("exploration_kwargs['temperature']", temperature, 0.0, float("inf"),
                     open_low=True, open_high=True)
        self.temperature = float(temperature)

    def select(
        self, candidates: th.Tensor, q_values: th.Tensor, n_elite: int, discrete_dims: Mapping[int, int]
    ) -> th.Tensor:
        """The drawn candidate of each row (``n_elite`` is not read; see :class:`ChunkSelector`)."""
        rows = th.arange(candidates.shape[0], device=candidates.device)
        drawn = softmax_candidate(pessimistic_q(q_values), self.temperature)  # (m,)
        return candidates[rows, drawn]  # (m, S, k, A) -> (m, k, A)


class UncertaintyExploration:
    """
    One candidate drawn with the weights of the uncertainty-aware selection
    (:func:`~sb3_ua2c.chunking.uncertainty_weights`: ``softmax(mean_j Q_j / tau)``, ``tau`` the critics'
    disagreement), from torch's global random stream. The rollouts then explore around what ``predict`` does
    under ``selection="uncertainty"``, whose chunk is the mean of this draw; near uniform where the critics
    cannot yet rank the candidates, near the best where they can. Not in the paper. No own arguments.
    """

    def select(
        self, candidates: th.Tensor, q_values: th.Tensor, n_elite: int, discrete_dims: Mapping[int, int]
    ) -> th.Tensor:
        """The drawn candidate of each row (``n_elite`` is not read; see :class:`ChunkSelector`)."""
        rows = th.arange(candidates.shape[0], device=candidates.device)
        drawn = th.multinomial(uncertainty_weights(q_values), 1).squeeze(1)  # (m, S) -> (m,)
        return candidates[rows, drawn]  # (m, S, k, A) -> (m, k, A)


#: the exploration rules by ``exploration``: act as ``predict``, a softmax draw over the candidates by
#: ``min_j Q_j``, or a draw with the uncertainty-aware selection's weights
EXPLORATIONS: dict[str, type] = {
    "plan": PlanExploration,
    "softmax": SoftmaxExploration,
    "uncertainty": UncertaintyExploration,
}


__all__ = ["EXPLORATIONS", "ChunkSelector", "PlanExploration", "SoftmaxExploration", "UncertaintyExploration"]
