"""UA2C with offline data: logged episodes in the replay buffer, Phase-1 pre-training from it, and the
calibration of the quantile execution rule on histories of the data.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.2 (Eq. 4).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

import numpy as np
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.utils import configure_logger

from sb3_ua2c.checks import check_int
from sb3_ua2c.execution import CALIBRATION_SAMPLES
from sb3_ua2c.offline import Episode

SelfOfflineTraining = TypeVar("SelfOfflineTraining", bound="OfflineTraining")


class OfflineTraining(OffPolicyAlgorithm):
    """
    The offline-data methods of :class:`~sb3_ua2c.ua2c.UA2C` (a part of it, not an algorithm of its own):
    :meth:`add_offline_episodes`, :meth:`pretrain` (Phase 1) and :meth:`calibrate_execution`.
    """

    def add_offline_episodes(self, episodes: Iterable[Any], actions_normalized: bool = False) -> int:
        """
        Add logged episodes to the offline part of the replay buffer (sampled as k-step windows with
        the logged actions as the chunk, Eq. 4; mixed into each batch with ``offline_ratio``).

        :param episodes: :class:`~sb3_ua2c.offline.Episode` objects (e.g. those of a
            :class:`~sb3_ua2c.offline.OfflineDataset`) or mappings with their field names
        :param actions_normalized: ``True`` if the actions are already in [-1, 1] (else they are in
            the env's action units and are rescaled with the policy's ``scale_action``)
        :return: number of steps added
        """

        return self.replay_buffer.add_offline_episodes(self._normalized_episodes(episodes, actions_normalized))

    def _normalized_episodes(self, episodes: Iterable[Any], actions_normalized: bool) -> Iterator[Episode]:
        """Episodes with actions in [-1, 1] (rescaled with ``scale_action`` unless ``actions_normalized``)."""
        for ep in episodes:
            episode = Episode.coerce(ep)
            if actions_normalized:
                yield episode
                continue
            actions = np.asarray(episode.actions, dtype=np.float32)
            scaled = self.policy.scale_action(actions.reshape(actions.shape[0], -1))
            yield dataclasses.replace(episode, actions=np.clip(scaled, -1.0, 1.0))

    def pretrain(
        self: SelfOfflineTraining, n_gradient_steps: int, batch_size: int | None = None, log_interval: int = 1000
    ) -> SelfOfflineTraining:
        """
        Phase 1: train actor and critics from the replay buffer (typically offline episodes only)
        without any environment interaction. Uses the same :meth:`train` step as online learning.

        :param n_gradient_steps: number of gradient steps
        :param batch_size: minibatch size (default: ``self.batch_size``)
        :param log_interval: dump the logger every ``log_interval`` gradient steps
        :return: this model
        """
        check_int("n_gradient_steps", n_gradient_steps, low=0)
        if log_interval < 1:
            raise ValueError(f"log_interval must be >= 1, got {log_interval!r}")
        n_online, n_offline = self.replay_buffer.n_samples()
        if n_online + n_offline == 0:
            raise ValueError("pretrain needs data: add offline episodes with add_offline_episodes() first")
        if not hasattr(self, "_logger"):
            self.set_logger(configure_logger(self.verbose, self.tensorboard_log, "pretrain"))
        done = 0
        while done < n_gradient_steps:
            steps = min(log_interval, n_gradient_steps - done)
            self.train(gradient_steps=steps, batch_size=batch_size or self.batch_size)
            done += steps
            self.logger.record("pretrain/gradient_steps", done)
            self.logger.dump(step=self._n_updates)
        return self

    def calibrate_execution(
        self,
        n_histories: int = 1024,
        n_samples: int = CALIBRATION_SAMPLES,
        episodes: Iterable[Any] | None = None,
        actions_normalized: bool = False,
    ) -> np.ndarray:
        """
        Calibrate ``execution_rule="quantile"``: draw ``n_histories`` histories from the replay buffer
        (after Phase 1: the dataset) or from held-out ``episodes``, measure ``H_u`` at each with
        ``n_samples`` fresh-noise candidates, and set the per-position thresholds ``delta_u`` to the
        ``entropy_quantile`` of ``H_u``
        (:meth:`~sb3_ua2c.execution.ExecutionRuleState.calibrate_entropy_thresholds`). Saved with the
        model. The draw and the noise come from the model's random generators (seeded by ``seed``), as a
        training batch's do.

        :param n_histories: histories drawn (with replacement, as a training batch)
        :param n_samples: candidates per history
        :param episodes: held-out episodes to draw the histories from instead of the replay buffer (as
            :meth:`add_offline_episodes` takes them): histories the model was not trained on
        :param actions_normalized: with ``episodes``: their actions are already in [-1, 1]
        :return: the measured ``H_u``, shape ``(n_histories, k)``
        """
        check_int("n_histories", n_histories, low=2)
        buffer = self.replay_buffer
        if episodes is not None:
            buffer = self._make_replay_buffer(self.chunk_size + self.history_len)  # an empty online ring
            if buffer.add_offline_episodes(self._normalized_episodes(episodes, actions_normalized)) == 0:
                raise ValueError("calibrate_execution: episodes holds no steps")
        n_online, n_offline = buffer.n_samples()
        if n_online + n_offline == 0:
            raise ValueError(
                "calibrate_execution needs histories in the replay buffer: add offline episodes "
                "(add_offline_episodes) or collect steps first (learning_starts > 0), or pass episodes="
            )
        data = buffer.sample(n_histories, env=self._vec_normalize_env)
        entropy = self.policy.calibrate_entropy_thresholds(data.observation_history, data.action_history, n_samples)
        return entropy.cpu().numpy()


__all__ = ["OfflineTraining"]
