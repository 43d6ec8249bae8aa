"""UA2C's plug-in options beyond the paper, each a name and its class's own arguments
(:mod:`sb3_ua2c.registry`): the critics' bootstrap (``critic_target``, :mod:`sb3_ua2c.targets`), the
actor's extraction (``actor_extraction``, :mod:`sb3_ua2c.extraction`) and the rollouts' exploration
(``exploration``, :mod:`sb3_ua2c.exploration`). One path checks and builds them: the constructor,
``load`` and the setters.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sb3_ua2c.config import check_arguments
from sb3_ua2c.exploration import EXPLORATIONS
from sb3_ua2c.extraction import ACTOR_EXTRACTIONS
from sb3_ua2c.registry import build, resolved_kwargs
from sb3_ua2c.targets import CRITIC_TARGETS, TargetInputs

#: the options by UA2C's argument name, and their registries
OPTIONS = {
    "critic_target": CRITIC_TARGETS,
    "actor_extraction": ACTOR_EXTRACTIONS,
    "exploration": EXPLORATIONS,
}
#: UA2C's argument names of the options and of their kwargs
OPTION_ARGUMENTS = tuple(name for option in OPTIONS for name in (option, f"{option}_kwargs"))


class TrainingOptions(OffPolicyAlgorithm):
    """
    The options ``critic_target``, ``actor_extraction`` and ``exploration`` of
    :class:`~sb3_ua2c.ua2c.UA2C` (a part of it, not an algorithm of its own). ``model.critic_target``
    stays the target critics (SB3's name); the bootstrap's name is ``critic_target_name``.
    """

    def _option_arguments(self) -> dict[str, Any]:
        """The options' names and (resolved) kwargs, by UA2C's argument names."""
        return {
            "critic_target": self.critic_target_name,
            "critic_target_kwargs": self.critic_target_kwargs,
            "actor_extraction": self.actor_extraction,
            "actor_extraction_kwargs": self.actor_extraction_kwargs,
            "exploration": self.exploration,
            "exploration_kwargs": self.exploration_kwargs,
        }

    def _configure_options(self, with_policy: bool, **changes: Any) -> None:
        """
        Check, build and set the options: the current ones with ``changes`` applied (a ``None`` kwargs:
        the class's defaults). With the policy built, its value network follows ``critic_target``.

        :param with_policy: the policy exists (check ``actor_type``, build or drop ``V``)
        :param changes: option arguments by UA2C's names
        """
        args = {**self._option_arguments(), **changes}
        check_arguments(**args, **({"actor_type": self.policy.actor_type} if with_policy else {}))
        rules = {option: build(registry, args[option], args[f"{option}_kwargs"], option)
                 for option, registry in OPTIONS.items()}
        for option, registry in OPTIONS.items():
            args[f"{option}_kwargs"] = resolved_kwargs(registry, args[option], args[f"{option}_kwargs"])
        if with_policy:
            learning_rate = self.lr_schedule(self._current_progress_remaining)
            self.policy._set_value(rules["critic_target"].value_arch, learning_rate)
        self.critic_target_name = args["critic_target"]
        self.critic_target_kwargs = args["critic_target_kwargs"]
        self.actor_extraction = args["actor_extraction"]
        self.actor_extraction_kwargs = args["actor_extraction_kwargs"]
        self.exploration = args["exploration"]
        self.exploration_kwargs = args["exploration_kwargs"]
        self._target_rule, self._extraction_rule = rules["critic_target"], rules["actor_extraction"]
        self._exploration_rule = rules["exploration"]

    def set_critic_target(
        self, critic_target: str, critic_target_kwargs: dict[str, Any] | None = None
    ) -> None:
        """
        Change the bootstrap of the critics' targets, e.g. after Phase 1:
        ``model.set_critic_target("in_sample", {"expectile": 0.9})``. ``"in_sample"`` builds the value
        network ``V`` (with a fresh optimizer) when the policy has none of those sizes; ``"candidates"``
        drops it. Kept by ``save``; ``UA2C.load(path, critic_target=...)`` calls it. The one setter of
        ``critic_target`` and ``critic_target_kwargs``.

        :param critic_target: a key of :data:`~sb3_ua2c.targets.CRITIC_TARGETS`
        :param critic_target_kwargs: its class's own arguments (``None``: its defaults)
        """
        self._configure_options(True, critic_target=critic_target, critic_target_kwargs=critic_target_kwargs)

    def set_actor_extraction(
        self, actor_extraction: str, actor_extraction_kwargs: dict[str, Any] | None = None
    ) -> None:
        """
        Change the actor's extraction (kept by ``save``; ``load(path, actor_extraction=...)`` calls it).

        :param actor_extraction: a key of :data:`~sb3_ua2c.extraction.ACTOR_EXTRACTIONS`
        :param actor_extraction_kwargs: its class's own arguments (``None``: its defaults)
        """
        self._configure_options(
            True, actor_extraction=actor_extraction, actor_extraction_kwargs=actor_extraction_kwargs
        )

    def set_exploration(self, exploration: str, exploration_kwargs: dict[str, Any] | None = None) -> None:
        """
        Change how training rollouts choose the executed candidate (kept by ``save``;
        ``load(path, exploration=...)`` calls it). ``predict`` is not affected.

        :param exploration: a key of :data:`~sb3_ua2c.exploration.EXPLORATIONS`
        :param exploration_kwargs: its class's own arguments (``None``: its defaults)
        """
        self._configure_options(True, exploration=exploration, exploration_kwargs=exploration_kwargs)

    def _target_inputs(self) -> TargetInputs:
        return TargetInputs(self.policy, self.n_target_candidates, self.target_flow_steps)


def option_changes(kwargs: dict[str, Any]) -> dict[str, Any]:
    """
    Pop the option arguments from ``load``'s keyword arguments: an option named without its kwargs
    takes its class's defaults (as its setter does).

    :param kwargs: ``load``'s keyword arguments (modified in place)
    :return: the changes for :meth:`TrainingOptions._configure_options`
    """
    changes = {name: kwargs.pop(name) for name in OPTION_ARGUMENTS if name in kwargs}
    for option in OPTIONS:
        if option in changes:
            changes.setdefault(f"{option}_kwargs", None)
    return changes


__all__ = ["OPTIONS", "OPTION_ARGUMENTS", "TrainingOptions", "option_changes"]
