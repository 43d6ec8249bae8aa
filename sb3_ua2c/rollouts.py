"""UA2C's rollouts: adaptive chunk execution in the environments and the chunk transitions it stores.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3 (Eq. 7, 8).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.type_aliases import RolloutReturn, TrainFreq
from stable_baselines3.common.utils import safe_mean, should_collect_more_steps
from stable_baselines3.common.vec_env import VecEnv

from sb3_ua2c.buffers import ChunkReplayBuffer
from sb3_ua2c.execution import AdaptiveChunkExecutor, ExecutorStep, PlanResult


class ChunkRollouts(OffPolicyAlgorithm):
    """
    The rollouts of :class:`~sb3_ua2c.ua2c.UA2C` (a part of it, not an algorithm of its own): each env
    executes the reliable prefix ``L_t`` of its plan (Eq. 7) and replans when it is used up or an
    episode starts, through one :class:`~sb3_ua2c.execution.AdaptiveChunkExecutor` per number of envs;
    every step goes into the :class:`~sb3_ua2c.buffers.ChunkReplayBuffer` with the plan it belongs to.
    During the ``learning_starts`` warm-up, plans are uniform random chunks executed in full.
    """

    def _random_plan(self, obs_history: np.ndarray, action_history: np.ndarray) -> PlanResult:
        m = obs_history.shape[0]
        # NumPy's global RNG, seeded by SB3's set_random_seed like its own warm-up sampling
        chunks = np.random.uniform(-1.0, 1.0, size=(m, self.chunk_size, self.policy.action_dim))  # noqa: NPY002
        chunks = chunks.astype(np.float32)
        return PlanResult(
            chunks, np.full(m, self.chunk_size), np.full((m, self.chunk_size), np.nan, dtype=np.float32)
        )

    def _get_executor(self, n_envs: int) -> AdaptiveChunkExecutor:
        if self._executor is None or self._executor.n_envs != n_envs:
            self._executor = AdaptiveChunkExecutor(
                n_envs, self.policy.obs_dim, self.policy.action_dim, self.chunk_size, self.history_len
            )
        return self._executor

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        train_freq: TrainFreq,
        replay_buffer: ReplayBuffer,
        action_noise: ActionNoise | None = None,
        learning_starts: int = 0,
        log_interval: int | None = None,
    ) -> RolloutReturn:
        """
        Collect experience with adaptive chunk execution and store it in the chunk replay buffer.

        :param env: the training environment
        :param callback: callback called at each step
        :param train_freq: how much experience to collect
        :param replay_buffer: the :class:`ChunkReplayBuffer`
        :param action_noise: optional exploration noise added to executed actions
        :param learning_starts: steps of random chunks before the policy acts
        :param log_interval: log every ``log_interval`` episodes
        :return: the rollout summary
        """
        self.policy.set_training_mode(False)
        num_collected_steps, num_collected_episodes = 0, 0
        assert isinstance(env, VecEnv), "You must pass a VecEnv"
        assert isinstance(replay_buffer, ChunkReplayBuffer)
        assert train_freq.frequency > 0, "Should at least collect one step or episode."
        if env.num_envs > 1 and train_freq.unit.value != "step":
            raise ValueError("train_freq must be in steps when using several environments")
        executor = self._get_executor(env.num_envs)
        n_envs = env.num_envs

        def policy_plan(obs_h: np.ndarray, act_h: np.ndarray) -> PlanResult:
            if self.policy.needs_calibration:
                self.calibrate_execution()
            return self.policy.plan(obs_h, act_h, deterministic=False, record_entropy=True,
                                    selector=self._exploration_rule)

        callback.on_rollout_start()
        continue_training = True
        n_new_plans = 0
        while should_collect_more_steps(train_freq, num_collected_steps, num_collected_episodes):
            warmup = self.num_timesteps < learning_starts
            noise = None
            if action_noise is not None and not warmup:
                noise = np.asarray(action_noise(), dtype=np.float32).reshape(-1, self.policy.action_dim)
            assert self._last_obs is not None and not isinstance(self._last_obs, dict)
            episode_start = np.asarray(self._last_episode_starts, dtype=bool).reshape(n_envs)
            step = executor.act(
                np.asarray(self._last_obs).reshape(n_envs, -1),
                episode_start,
                self._random_plan if warmup else policy_plan,
                noise,
                self.policy.ensemble_decay,
                self.policy.continuous_dims,
            )
            n_new_plans += int(step.new_plan.sum())
            if not warmup:
                self._record_plans(step)
            actions = self.policy.unscale_action(step.actions).reshape((n_envs, *self.action_space.shape))
            new_obs, rewards, dones, infos = env.step(actions)

            self.num_timesteps += n_envs
            num_collected_steps += 1
            callback.update_locals(locals())
            if not callback.on_step():
                return RolloutReturn(n_new_plans, num_collected_episodes, continue_training=False)

            self._update_info_buffer(infos, dones)
            self._store_chunk_transition(replay_buffer, step, episode_start, new_obs, rewards, dones, infos)
            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            self._on_step()
            for idx, done in enumerate(dones):
                if done:
                    num_collected_episodes += 1
                    self._episode_num += 1
                    if action_noise is not None:
                        kwargs = dict(indices=[idx]) if n_envs > 1 else {}
                        action_noise.reset(**kwargs)
                    if log_interval is not None and self._episode_num % log_interval == 0:
                        self.dump_logs()
        callback.on_rollout_end()
        # ``episode_timesteps`` is what SB3's learn() uses for ``gradient_steps=-1``: UA2C counts plans
        return RolloutReturn(n_new_plans, num_collected_episodes, continue_training)

    def _record_plans(self, step: ExecutorStep) -> None:
        for i in np.flatnonzero(step.new_plan):
            self._plan_lengths.append(float(step.plan_lengths[i]))
            self._plan_entropy.append(step.entropy[i])

    def _store_chunk_transition(
        self,
        replay_buffer: ChunkReplayBuffer,
        step: ExecutorStep,
        episode_start: np.ndarray,
        new_obs: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step (original, unnormalised observations and rewards, as SB3 does)."""
        if self._vec_normalize_env is not None:
            new_obs_ = self._vec_normalize_env.get_original_obs()
            reward_ = self._vec_normalize_env.get_original_reward()
        else:
            self._last_original_obs, new_obs_, reward_ = self._last_obs, new_obs, rewards
        next_obs = np.array(new_obs_, dtype=np.float32, copy=True)
        truncated = np.zeros(len(dones), dtype=bool)
        for i, done in enumerate(dones):
            if not done:
                continue
            truncated[i] = bool(infos[i].get("TimeLimit.truncated", False))
            terminal = infos[i].get("terminal_observation")
            if terminal is not None:
                if self._vec_normalize_env is not None:
                    terminal = self._vec_normalize_env.unnormalize_obs(terminal)
                next_obs[i] = terminal
        dones = np.asarray(dones, dtype=bool)
        replay_buffer.add(
            self._last_original_obs,  # type: ignore[arg-type]
            next_obs,
            step.actions,
            reward_,
            dones & ~truncated,
            truncated,
            episode_start,
            step.new_plan,
            step.plans,
            step.plan_lengths,
        )
        self._last_obs = new_obs
        self._last_episode_starts = dones
        if self._vec_normalize_env is not None:
            self._last_original_obs = new_obs_

    def dump_logs(self) -> None:
        if self._plan_lengths:
            entropy = np.stack(list(self._plan_entropy))  # (plans, k)
            self.logger.record("rollout/executed_length", safe_mean(list(self._plan_lengths)))
            self.logger.record("rollout/entropy_mean", float(np.mean(entropy)))
            self.logger.record("rollout/entropy_first", float(np.mean(entropy[:, 0])))
            self.logger.record("rollout/entropy_last", float(np.mean(entropy[:, -1])))
        if self.policy.entropy_window is not None:
            self.logger.record("rollout/entropy_threshold", float(self.policy.current_entropy_threshold()))
        super().dump_logs()

    @property
    def last_executed_length(self) -> float:
        """Mean ``L_t`` of the recent training plans (``nan`` before the first policy plan)."""
        return float(np.mean(self._plan_lengths)) if self._plan_lengths else math.nan


__all__ = ["ChunkRollouts"]
