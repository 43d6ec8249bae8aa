"""UA2C's checkpoints: what a saved model holds, SB3's ``load`` with the overrides UA2C adds, and clear
errors for checkpoints that do not fit (the conversion of earlier layouts is :mod:`sb3_ua2c.compat`).
"""

from __future__ import annotations

import dataclasses
import io
import pathlib
from typing import Any

import torch as th
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.save_util import load_from_pkl, load_from_zip_file
from stable_baselines3.common.type_aliases import GymEnv

from sb3_ua2c.buffers import ChunkReplayBuffer
from sb3_ua2c.compat import LEGACY_RULE_NAMES, legacy_critic_kwargs
from sb3_ua2c.options import option_changes


class CheckpointMismatchError(ValueError, RuntimeError):
    """A checkpoint whose networks do not fit the model it is loaded into. A ``ValueError`` for callers;
    also a ``RuntimeError``, because SB3's ``load`` re-raises a ``RuntimeError`` of ``set_parameters`` as it
    is, where it would turn a plain ``ValueError`` into a ``KeyError`` of its DQN-checkpoint patch."""


class Checkpoints(OffPolicyAlgorithm):
    """
    Saving and loading of :class:`~sb3_ua2c.ua2c.UA2C` (a part of it, not an algorithm of its own).
    """

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "actor",
            "critic",
            "critic_target",
            "_executor",
            "_plan_lengths",
            "_plan_entropy",
            "_target_rule",
            "_extraction_rule",
            "_exploration_rule",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        value = [] if self.policy.value is None else ["policy.value.optimizer"]  # critic_target="in_sample"
        return ["policy", "actor.optimizer", "critic.optimizer", *value], []

    @classmethod
    def load(  # type: ignore[override]
        cls,
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> Any:
        """
        SB3's ``load``; keyword arguments override the saved attributes as in SB3
        (``UA2C.load(path, gradient_steps=2)``). The acting settings go through their one setter after
        loading: ``n_elite=m`` (:meth:`~sb3_ua2c.ua2c.UA2C.set_n_elite`; SB3 would store it as an unused
        attribute), ``selection`` (:meth:`~sb3_ua2c.ua2c.UA2C.set_selection`), ``flow_steps`` (:meth:`~sb3_ua2c.ua2c.UA2C.set_flow_steps`) and the execution rule's
        fields by UA2C's argument names, ``execution_rule``, ``entropy_threshold``, ... (the saved rule
        with those fields replaced, :meth:`~sb3_ua2c.ua2c.UA2C.set_execution_rule`). A ``policy_kwargs``
        given (as rl-zoo3 passes its YAML's when continuing) must equal the saved one, as in SB3, after both
        are read in the current layout (:func:`~sb3_ua2c.compat.legacy_critic_kwargs`). The options
        ``critic_target``, ``actor_extraction``, ``exploration`` and their ``*_kwargs`` are applied together
        through the setters' one path (:meth:`~sb3_ua2c.options.TrainingOptions.set_critic_target`, ...): a
        checkpoint without a value network gets one with ``critic_target="in_sample"``.
        """
        if "policy_kwargs" in kwargs and isinstance(path, str | pathlib.Path):
            data, _, _ = load_from_zip_file(path, load_data=True, device="cpu", print_system_info=False)
            saved = (data or {}).get("policy_kwargs")
            if legacy_critic_kwargs(saved) == legacy_critic_kwargs(kwargs["policy_kwargs"]):
                kwargs.pop("policy_kwargs")  # the same networks, saved in an earlier layout
        n_elite, flow_steps = kwargs.pop("n_elite", None), kwargs.pop("flow_steps", None)
        selection = kwargs.pop("selection", None)
        options = option_changes(kwargs)
        rule_fields = {field: kwargs.pop(name) for name, field in LEGACY_RULE_NAMES.items() if name in kwargs}
        model = super().load(
            path,
            env=env,
            device=device,
            custom_objects=custom_objects,
            print_system_info=print_system_info,
            force_reset=force_reset,
            **kwargs,
        )
        if options:
            model._configure_options(True, **options)
        if rule_fields:
            model.set_execution_rule(dataclasses.replace(model.execution, **rule_fields))
        if n_elite is not None:
            model.set_n_elite(n_elite)
        if selection is not None:
            model.set_selection(selection)
        if flow_steps is not None:
            model.set_flow_steps(flow_steps)
        return model

    def set_parameters(
        self,
        load_path_or_dict: str | pathlib.Path | io.BufferedIOBase | dict[str, Any],
        exact_match: bool = True,
        device: th.device | str = "auto",
    ) -> None:
        """
        SB3's ``set_parameters``; a checkpoint whose networks do not fit this model (other sizes,
        or the layer-norm critics of early development versions, whose ``norm*.bias`` entries the
        RMS-norm critics no longer have) raises a :class:`CheckpointMismatchError` (a ``ValueError``) that
        says so.
        """
        try:
            super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)
        except RuntimeError as error:
            if "state_dict" not in str(error):
                raise
            hint = ""
            if ".norm" in str(error) and ".bias" in str(error):
                hint = (
                    " The checkpoint has layer-norm biases in its critics: it was saved by an early"
                    " development version (the critics now use RMS norms); retrain it."
                )
            raise CheckpointMismatchError(
                f"the checkpoint's networks do not match this UA2C model (chunk_size, history_len, "
                f"policy_kwargs and the spaces must be those it was trained with).{hint}\n{error}"
            ) from error

    def load_replay_buffer(
        self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True
    ) -> None:
        """
        Load a :class:`ChunkReplayBuffer` saved with :meth:`save_replay_buffer`.

        :param path: path to the pickled replay buffer
        :param truncate_last_traj: unused (kept for SB3 compatibility)
        """
        buffer = load_from_pkl(path, self.verbose)
        if not isinstance(buffer, ChunkReplayBuffer):
            raise ValueError(f"expected a ChunkReplayBuffer, got {type(buffer).__name__}")
        buffer.device = self.device
        self.replay_buffer = buffer


__all__ = ["CheckpointMismatchError", "Checkpoints"]
