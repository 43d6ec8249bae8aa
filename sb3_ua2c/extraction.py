"""How the actor is extracted from the critics, by name: UA2C's ``actor_extraction`` picks a class of
:data:`ACTOR_EXTRACTIONS` and ``actor_extraction_kwargs`` holds its own arguments, whose defaults are
in its signature (:mod:`sb3_ua2c.registry`). ``"value_term"`` is the paper's Eq. 2 (the objective of
the ``actor_type``'s class, :func:`~sb3_ua2c.actors.actor_objective`); ``"awr"`` (not in the paper)
weights the flow matching of the data's chunks by their advantage under the in-sample value.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th

from sb3_ua2c.actor_objectives import ActorObjective, ActorWeights, advantage_weighted_objective
from sb3_ua2c.actors import actor_objective
from sb3_ua2c.checks import check_number
from sb3_ua2c.chunking import pessimistic_q
from sb3_ua2c.in_sample_maths import advantage_weights


class ValueTermExtraction:
    """The actor objective of the policy's ``actor_type`` (Eq. 2's ``-λ Q(x̂1)``, or QC-FQL's one-step
    policy): no own arguments, no value network."""

    #: needs the policy's value network ``V`` (``critic_target="in_sample"``)
    needs_value: ClassVar[bool] = False
    #: the actor types it trains (``None``: all of :data:`~sb3_ua2c.actors.ACTORS`)
    actor_types: ClassVar[tuple[str, ...] | None] = None

    def objective(
        self, policy: Any, data: Any, weights: ActorWeights, generator: th.Generator | None = None
    ) -> ActorObjective:
        """
        :param policy: the policy (:class:`~sb3_ua2c.policies.UA2CPolicy`: its actors and critics)
        :param data: the batch
        :param weights: the objective's weights (``UA2C.actor_weights``)
        :param generator: the random stream (``None``: torch's global one, as in training)
        """
        return actor_objective(policy.actor_type, policy.actor_inputs(), data, weights, generator)


class AdvantageWeightedExtraction:
    """
    Advantage-weighted regression of the flow on the data's chunks (AWR, Peng et al., 2019; IQL's
    extraction, Kostrikov et al., 2022; for a flow policy as IFQL, Park et al., 2025): each chunk's
    flow-matching error weighted by ``min(exp(β (min_j Q̄_j(h, a) - V(h))), w_max)``
    (:func:`~sb3_ua2c.in_sample_maths.advantage_weights`, the target critics and the in-sample ``V`` as d3rlpy's
    IQL), and no value term (``q_weight`` and ``normalize_q`` are not read). The actor still acts by the
    best of S candidates under ``Q``. It needs ``critic_target="in_sample"`` (the ``V`` fitted by
    expectile regression) and ``actor_type="flow"``: QC-FQL's one-step policy is trained by a value term
    only, which this extraction replaces.

    :param temperature: ``β >= 0`` (d3rlpy's IQL: 3.0; 0 = plain flow matching)
    :param max_weight: ``w_max > 0`` (d3rlpy's IQL: 100)
    """

    needs_value: ClassVar[bool] = True
    actor_types: ClassVar[tuple[str, ...] | None] = ("flow",)

    def __init__(self, temperature: float = 3.0, max_weight: float = 100.0) -> None:
        check_number("actor_extraction_kwargs['temperature']", temperature, 0.0, float("inf"),
                     open_low=False, open_high=True)
        check_number("actor_extraction_kwargs['max_weight']", max_weight, 0.0, float("inf"),
                     open_low=True, open_high=True)
        self.temperature = float(temperature)
        self.max_weight = float(max_weight)

    def objective(
        self, policy: Any, data: Any, weights: ActorWeights, generator: th.Generator | None = None
    ) -> ActorObjective:
        """
        :param policy: the policy (:class:`~sb3_ua2c.policies.UA2CPolicy`: its velocity field,
            ``critic_target`` and ``value``)
        :param data: the batch
        :param weights: ``smooth_weight`` and ``past_action_dropout`` are read
        :param generator: the random stream (``None``: torch's global one, as in training)
        :return: the objective, with ``awr_weight_mean`` and ``awr_weight_max`` logged
        """
        obs_flat = data.observation_history.flatten(1)  # (B, ℓ, obs_dim) -> (B, ℓ*obs_dim)
        with th.no_grad():
            q = pessimistic_q(policy.critic_target(obs_flat, data.chunks.unsqueeze(1)))[:, 0]  # (n, B, 1) -> (B,)
            w = advantage_weights(q, policy.value(obs_flat), self.temperature, self.max_weight)  # (B,)
        out = advantage_weighted_objective(policy.actor_inputs(), data, weights, w, generator)
        out.info.update(awr_weight_mean=w.mean().item(), awr_weight_max=w.max().item())
        return out


#: the extractions by ``actor_extraction``: the paper's value term, or advantage-weighted regression
ACTOR_EXTRACTIONS: dict[str, type] = {
    "value_term": ValueTermExtraction,
    "awr": AdvantageWeightedExtraction,
}


__all__ = ["ACTOR_EXTRACTIONS", "AdvantageWeightedExtraction", "ValueTermExtraction"]
