"""The bootstrap of the critics' targets (Eq. 4 / 8), by name: UA2C's ``critic_target`` picks a class of
:data:`CRITIC_TARGETS` and ``critic_target_kwargs`` holds that class's own arguments, whose defaults are
in its signature (:mod:`sb3_ua2c.registry`). ``UA2C`` asks a target class for :class:`CriticTarget`
only: the value of the next history in ``y = Σ_{u<L} γ^u r + m γ^L V(h_{t+L})``
(:func:`~sb3_ua2c.chunking.chunk_target`), and the loss of the value network it needs, if any.

A new bootstrap is one module with one class and one line in :data:`CRITIC_TARGETS`
(docs/algorithm.md, "Adding a critic or an actor").
"""

from __future__ import annotations

from sb3_ua2c.targets.base import CriticTarget, TargetInputs
from sb3_ua2c.targets.candidates import CandidateTarget
from sb3_ua2c.targets.in_sample import ChunkValue, InSampleTarget

#: the bootstraps by ``critic_target``: the paper's max over actor candidates, or IQL's in-sample value
CRITIC_TARGETS: dict[str, type] = {
    "candidates": CandidateTarget,
    "in_sample": InSampleTarget,
}


__all__ = [
    "CRITIC_TARGETS",
    "CandidateTarget",
    "ChunkValue",
    "CriticTarget",
    "InSampleTarget",
    "TargetInputs",
]
