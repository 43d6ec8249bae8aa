"""UA2C as a Stable-Baselines3 off-policy algorithm: rollouts with adaptive chunk execution, chunk-level
training (Eq. 2, 3, 4, 8), offline episodes and Phase-1 pre-training from the buffer.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.
"""

from __future__ import annotations

import io
import math
import pathlib
from collections import deque
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import load_from_pkl
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, RolloutReturn, Schedule, TrainFreq
from stable_baselines3.common.utils import (
    configure_logger,
    polyak_update,
    safe_mean,
    should_collect_more_steps,
)
from stable_baselines3.common.vec_env import VecEnv

from sb3_ua2c.buffers import ChunkReplayBuffer, ChunkReplaySamples, OfflineEpisode
from sb3_ua2c.checks import check_int
from sb3_ua2c.chunking import (
    bootstrap_value,
    chunk_critic_loss,
    chunk_target,
    pessimistic_q,
)
from sb3_ua2c.config import (
    EXECUTION_RULE_DEFAULTS,
    POLICY_CHUNKING_ARGUMENTS,
    check_arguments,
    check_policy_kwargs,
    check_spaces,
    hyperparameters,
    policy_arguments,
)
from sb3_ua2c.execution import AdaptiveChunkExecutor, ExecutorStep, PlanResult
from sb3_ua2c.flow import actor_loss, chunk_roughness, estimate_terminal, interpolate
from sb3_ua2c.policies import CALIBRATION_SAMPLES, MlpPolicy, UA2CPolicy

SelfUA2C = TypeVar("SelfUA2C", bound="UA2C")


class UA2C(OffPolicyAlgorithm):
    """
    UA2C: uncertainty-aware adaptive action chunking with a flow-matching chunk actor and twin
    Transformer chunk critics.

    Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
    Mixed Traffic" (§3, Eq. 2-4, 7, 8).

    Rollouts sample ``n_candidates`` chunks, keep the one with the highest ``min_j Q_j``, execute
    its reliable prefix ``L_t`` (Eq. 7) and replan; offline-to-online, each executed plan is one
    replay sample whose target is Eq. 8 (``L = L_t``; without offline data the default
    ``online_targets="auto"`` samples windows of executed actions instead). Offline episodes added with :meth:`add_offline_episodes` give
    k-step windows from any start with the logged actions (Eq. 4). ``entropy_threshold=inf`` is
    fixed chunk execution and ``chunk_size=1`` the one-step baseline, on the same code path.

    Design choices where the paper is silent: the history is padded at the episode start by
    repeating the first observation (zero past actions); the actor term of Eq. 2 averages the flow
    error over chunk entries and divides the value term by the batch mean ``|Q|``; targets use the
    current actor for the candidates and ``target_flow_steps`` Euler steps; ``H_u`` sums per-dim
    entropies (Gaussian for continuous dims, empirical categorical for ``discrete_action_dims``).
    ``predict(deterministic=True)`` starts the candidates of every history from noise seeded by a hash
    of that history, so a history's plan does not depend on the other envs of the batch. During the
    ``learning_starts`` warm-up, plans are uniform random chunks executed in full.

    :param policy: the policy model to use (``"MlpPolicy"`` or :class:`UA2CPolicy`)
    :param env: the environment to learn from (if registered in Gym, can be str)
    :param learning_rate: learning rate for Adam (actor and critics), constant or schedule
    :param buffer_size: size of the online replay ring (steps per env)
    :param learning_starts: steps of uniform random chunks before learning starts
    :param batch_size: minibatch size of each gradient step (chunk transitions)
    :param tau: Polyak coefficient of the target critics
    :param gamma: discount factor (per environment step; a chunk of length ``L`` is discounted by ``gamma^L``)
    :param train_freq: update the model every ``train_freq`` steps (int or ``(n, "step"|"episode")``)
    :param gradient_steps: gradient steps after each rollout; ``-1`` (default) = one per plan started
        during the rollout, i.e. one update per new chunk sample (SB3's ``-1`` counts env steps)
    :param action_noise: optional exploration noise added to the executed actions
    :param replay_buffer_class: must be ``None`` or :class:`ChunkReplayBuffer`
    :param replay_buffer_kwargs: extra arguments of the replay buffer
    :param chunk_size: chunk length ``k``
    :param history_len: history length ``ℓ`` (observations and past actions)
    :param flow_steps: Euler steps ``N`` when acting
    :param target_flow_steps: Euler steps for the target candidates (cheaper than acting)
    :param n_candidates: chunks ``S`` sampled per replanning
    :param n_target_candidates: candidate chunks ``Q`` in the target max (Eq. 4 / 8)
    :param execution_rule: how the executed length ``L_t`` follows from the per-position entropies ``H_u``
        of a replanning's candidates (docs/algorithm.md): ``"threshold"`` (default, Eq. 7): the longest
        prefix with every ``H_u <= entropy_threshold``; ``"quantile"`` (not in the paper): Eq. 7 with
        per-position thresholds ``delta_u``, the ``entropy_quantile`` of ``H_u`` over histories of the
        data, calibrated by :meth:`calibrate_execution` (``learn`` calibrates from the replay buffer
        when needed) and saved with the model; ``"growth"`` (not in the paper): the longest prefix with
        every ``H_u - H_1 <= entropy_growth``
    :param entropy_threshold: ``delta`` of Eq. 7 in nats (``math.inf`` = the whole chunk), or ``"auto"``: δ
        set after each training replanning from the entropies of the last ones, for a mean ``L_t`` of
        ``target_plan_length`` (:func:`~sb3_ua2c.chunking.auto_entropy_threshold`)
    :param target_plan_length: with ``entropy_threshold="auto"`` only: the target mean ``L_t`` in
        ``[1, k]`` (``None`` = ``(k + 1) / 2``)
    :param entropy_quantile: with ``execution_rule="quantile"`` only: ``q`` in ``[0, 1]``, a fraction of
        states (``None`` = :data:`~sb3_ua2c.config.DEFAULT_ENTROPY_QUANTILE`)
    :param entropy_growth: with ``execution_rule="growth"`` only: ``c`` in nats above ``H_1`` (``None`` =
        :data:`~sb3_ua2c.config.DEFAULT_ENTROPY_GROWTH`)
    :param q_weight: ``lambda``, weight of the value term in Eq. 2
    :param smooth_weight: ``mu``, weight of an in-chunk smoothness term added to Eq. 2 (not in the
        paper; 0 = Eq. 2): ``mu`` times the mean squared step change of the continuous actions
        inside the actor's terminal estimate x̂1. It does not act on ``chunk_size=1``.
    :param discrete_entropy: ``H_u`` of Eq. 7 sums the entropies of the continuous and the
        categorical action dims (``True``, default); ``False`` leaves the categorical dims out, so
        a disagreement of the candidates on a lane change alone does not end the executed prefix
    :param commit_discrete: ``True`` extends ``L_t`` through the first switch of a categorical
        action inside the selected chunk (not in the paper; default ``False`` = Eq. 7): a planned
        lane change is then executed before the next replanning instead of being postponed by it
        (:func:`~sb3_ua2c.chunking.commit_through_switch`)
    :param discrete_action_dims: ``{action index: category values}`` of categorical action dims,
        encoded by equal-width bins over the Box bounds (e.g. ``{1: [-1, 0, 1]}`` for a lane change
        with thresholds ±1/3)
    :param offline_ratio: fraction of each batch drawn from offline episodes (when any are stored)
    :param online_targets: ``"prefix"`` (Eq. 8): one online sample per plan, the target of its
        executed prefix ``L_t``; ``"window"`` (not in the paper): every executed step starts a k-step
        window of the actions executed next, across plan boundaries, with the target of Eq. 4, so
        that online samples mean what the offline windows mean; ``"auto"`` (default): chosen when
        the first online step is stored, ``"prefix"`` if the buffer holds offline episodes (and
        ``offline_ratio > 0``: offline-to-online, the paper's setting), ``"window"`` otherwise
        (online-only training); ``model.replay_buffer.active_online_targets`` says which
    :param stats_window_size: window size for the rollout logging
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param policy_kwargs: additional arguments of the policy (``net_arch``, ``critic_embed_dim``,
        ``critic_n_layers``, ``critic_n_heads``, ``critic_ff_dim``, ``n_critics``, ``activation_fn``,
        ``optimizer_class``, ``optimizer_kwargs``, ``torch_compile``: see :class:`UA2CPolicy`)
    :param verbose: verbosity level: 0 no output, 1 info, 2 debug
    :param seed: seed for the pseudo random generators
    :param device: device (cpu, cuda, ...) on which the code should be run
    :param _init_setup_model: whether or not to build the network at the creation of the instance
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: UA2CPolicy
    replay_buffer: ChunkReplayBuffer  # type: ignore[assignment]

    def __init__(
        self,
        policy: str | type[UA2CPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 1000,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = -1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | type[ChunkReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        chunk_size: int = 5,
        history_len: int = 4,
        flow_steps: int = 10,
        target_flow_steps: int = 2,
        n_candidates: int = 32,
        n_target_candidates: int = 2,
        execution_rule: str = "threshold",
        entropy_threshold: float | str = 0.0,
        target_plan_length: float | None = None,
        entropy_quantile: float | None = None,
        entropy_growth: float | None = None,
        q_weight: float = 1.0,
        smooth_weight: float = 0.0,
        discrete_entropy: bool = True,
        commit_discrete: bool = False,
        discrete_action_dims: Mapping[int, Sequence[float]] | None = None,
        offline_ratio: float = 0.5,
        online_targets: str = "auto",
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        if replay_buffer_class not in (None, ChunkReplayBuffer):
            raise ValueError(
                f"replay_buffer_class must be None or ChunkReplayBuffer, got {replay_buffer_class!r}"
            )
        env = maybe_make_env(env, verbose)
        if env is not None:
            check_spaces(env.observation_space, env.action_space)
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau,
            gamma,
            train_freq,
            gradient_steps,
            action_noise,
            replay_buffer_class=ChunkReplayBuffer,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=None,
            support_multi_env=True,
        )
        self.chunk_size = chunk_size
        self.history_len = history_len
        self.flow_steps = flow_steps
        self.target_flow_steps = target_flow_steps
        self.n_candidates = n_candidates
        self.n_target_candidates = n_target_candidates
        self.execution_rule = execution_rule
        self.entropy_threshold = entropy_threshold
        self.target_plan_length = target_plan_length
        self.entropy_quantile = entropy_quantile
        self.entropy_growth = entropy_growth
        self.q_weight = q_weight
        self.smooth_weight = smooth_weight
        self.discrete_entropy = discrete_entropy
        self.commit_discrete = commit_discrete
        self.discrete_action_dims = discrete_action_dims
        self.offline_ratio = offline_ratio
        self.online_targets = online_targets
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ setup
    def _setup_model(self) -> None:
        # the policy and the replay buffer check the arguments they take; UA2C checks the others
        delegated = {*policy_arguments(self.policy_class), *policy_arguments(ChunkReplayBuffer)}
        check_arguments(**{k: v for k, v in hyperparameters(self).items() if k not in delegated})
        check_spaces(self.observation_space, self.action_space)
        check_policy_kwargs(self.policy_kwargs, self.policy_class)
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space,
            self.action_space,
            self.lr_schedule,
            **{name: getattr(self, name) for name in POLICY_CHUNKING_ARGUMENTS},
            **self.policy_kwargs,
        )
        self.policy = self.policy.to(self.device)
        if self.replay_buffer is None:
            self.replay_buffer = self._make_replay_buffer(self.buffer_size)
        self._create_aliases()
        self._convert_train_freq()
        self._executor: AdaptiveChunkExecutor | None = None
        self._plan_lengths: deque[float] = deque(maxlen=1000)
        self._plan_entropy: deque[np.ndarray] = deque(maxlen=1000)

    def _make_replay_buffer(self, buffer_size: int) -> ChunkReplayBuffer:
        return ChunkReplayBuffer(
            buffer_size,
            self.observation_space,
            self.action_space,
            device=self.device,
            n_envs=self.n_envs,
            chunk_size=self.chunk_size,
            history_len=self.history_len,
            offline_ratio=self.offline_ratio,
            online_targets=self.online_targets,
            **self.replay_buffer_kwargs,
        )

    def _create_aliases(self) -> None:
        self.actor = self.policy.actor
        self.critic = self.policy.critic
        self.critic_target = self.policy.critic_target

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "actor",
            "critic",
            "critic_target",
            "_executor",
            "_plan_lengths",
            "_plan_entropy",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "actor.optimizer", "critic.optimizer"], []

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
    ) -> UA2C:
        """
        SB3's ``load``; keyword arguments override the saved attributes as in SB3
        (``UA2C.load(path, flow_steps=2)``), and ``n_elite=m`` sets the elite mean of the loaded
        policy (:meth:`set_n_elite`). Without that, SB3 would store ``n_elite`` as an unused
        attribute and the policy would go on acting with its saved ``m``.
        """
        n_elite = kwargs.pop("n_elite", None)
        model = super().load(
            path,
            env=env,
            device=device,
            custom_objects=custom_objects,
            print_system_info=print_system_info,
            force_reset=force_reset,
            **kwargs,
        )
        if n_elite is not None:
            model.set_n_elite(n_elite)
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
        RMS-norm critics no longer have) raises a ``ValueError`` that says so.
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
            raise ValueError(
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

    # ------------------------------------------------------------------ offline data
    def add_offline_episodes(self, episodes: Iterable[Any], actions_normalized: bool = False) -> int:
        """
        Add logged episodes to the offline part of the replay buffer (sampled as k-step windows with
        the logged actions as the chunk, Eq. 4; mixed into each batch with ``offline_ratio``).

        :param episodes: :class:`~sb3_ua2c.buffers.OfflineEpisode` objects, mappings or objects with the
            fields ``observations, actions, rewards, terminations, truncations[, next_observations]``
            (e.g. the episodes of a :class:`sb3_ua2c.offline.OfflineDataset`)
        :param actions_normalized: ``True`` if the actions are already in [-1, 1] (else they are in
            the env's action units and are rescaled with the policy's ``scale_action``)
        :return: number of steps added
        """

        return self.replay_buffer.add_offline_episodes(self._normalized_episodes(episodes, actions_normalized))

    def _normalized_episodes(self, episodes: Iterable[Any], actions_normalized: bool) -> Iterator[OfflineEpisode]:
        """Episodes as :class:`OfflineEpisode` with actions in [-1, 1] (rescaled unless ``actions_normalized``)."""
        for ep in episodes:
            episode = OfflineEpisode.coerce(ep)
            if actions_normalized:
                yield episode
                continue
            actions = np.asarray(episode.actions, dtype=np.float32)
            scaled = self.policy.scale_action(actions.reshape(actions.shape[0], -1))
            yield OfflineEpisode(
                episode.observations,
                np.clip(scaled, -1.0, 1.0),
                episode.rewards,
                episode.terminations,
                episode.truncations,
                episode.next_observations,
            )

    def pretrain(
        self: SelfUA2C, n_gradient_steps: int, batch_size: int | None = None, log_interval: int = 1000
    ) -> SelfUA2C:
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

    # ------------------------------------------------------------------ rollouts
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
            return self.policy.plan(obs_h, act_h, deterministic=False, record_entropy=True)

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

    def set_execution_rule(self, **rule: Any) -> None:
        """
        Change the execution rule (execution only; the losses do not depend on it), e.g. to evaluate
        one checkpoint under several rules. Keyword arguments as the constructor's ``execution_rule``,
        ``entropy_threshold``, ``target_plan_length``, ``entropy_quantile`` and ``entropy_growth``
        (validated alike); those not given take their defaults. ``"quantile"`` keeps calibrated
        thresholds (or needs :meth:`calibrate_execution`), ``"auto"`` keeps the entropy window (or starts
        an empty one). Kept by :meth:`save`.
        """
        self.policy.set_execution_rule(**rule)
        for name in EXECUTION_RULE_DEFAULTS:
            setattr(self, name, getattr(self.policy, name))

    def set_entropy_threshold(
        self, entropy_threshold: float | str, target_plan_length: float | None = None
    ) -> None:
        """
        Change δ of Eq. 7 (``execution_rule="threshold"``; execution only), e.g. to evaluate one
        checkpoint with fixed (``inf``) and adaptive execution; ``"auto"`` with ``target_plan_length``
        keeps the model's entropy window (or starts an empty one). Kept by :meth:`save`.

        :param entropy_threshold: the new threshold (validated like the constructor argument)
        :param target_plan_length: with ``"auto"`` only, the target mean ``L_t``
        """
        self.set_execution_rule(entropy_threshold=entropy_threshold, target_plan_length=target_plan_length)

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
        ``entropy_quantile`` of ``H_u`` (:meth:`UA2CPolicy.calibrate_entropy_thresholds`). Saved with the
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

    def set_n_elite(self, n_elite: int) -> None:
        """
        Change how many best candidates a replanning averages (``policy_kwargs["n_elite"]``, see
        :func:`~sb3_ua2c.chunking.select_chunk`; execution only, kept by :meth:`save`).

        :param n_elite: in ``[1, n_candidates]``
        """
        self.policy.set_n_elite(n_elite)
        # a new dict: ``policy_kwargs`` may be the caller's own (SB3 keeps the reference)
        self.policy_kwargs = {**self.policy_kwargs, "n_elite": self.policy.n_elite}

    def set_flow_steps(self, flow_steps: int) -> None:
        """
        Change the Euler steps ``N`` of the flow sampler when acting (execution only: the losses use
        the one-step estimate of Eq. 2 and ``target_flow_steps``; kept by :meth:`save`).

        :param flow_steps: >= 1
        """
        check_arguments(flow_steps=flow_steps)
        self.flow_steps = self.policy.flow_steps = flow_steps

    @property
    def last_executed_length(self) -> float:
        """Mean ``L_t`` of the recent training plans (``nan`` before the first policy plan)."""
        return float(np.mean(self._plan_lengths)) if self._plan_lengths else math.nan

    # ------------------------------------------------------------------ training
    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """
        ``gradient_steps`` updates of the critics (Eq. 3 with targets Eq. 4 / 8), the actor (Eq. 2)
        and the Polyak targets, each on ``batch_size`` chunk transitions.
        """
        n_online, n_offline = self.replay_buffer.n_samples()
        if n_online + n_offline == 0:
            return
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        logged: dict[str, list[float]] = {}  # {stat of _gradient_step: one value per update}
        for _ in range(gradient_steps):
            self._n_updates += 1
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            for key, value in self._gradient_step(data).items():
                logged.setdefault(key, []).append(value)
        self.policy.set_training_mode(False)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, values in logged.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))

    def _gradient_step(self, data: ChunkReplaySamples) -> dict[str, float]:
        """One update of the critics (Eq. 3 with the target of Eq. 4 / 8), the actor (Eq. 2) and the targets."""
        obs_flat = data.observation_history.flatten(1)  # (B, ℓ, obs_dim) -> (B, ℓ*obs_dim)
        with th.no_grad():
            next_value = self._next_values(data.next_observation_history, data.next_action_history)
            target = chunk_target(data.rewards, data.horizons, data.bootstrap, next_value, self.gamma)  # (B,)
        q = self.critic(obs_flat, data.chunks.unsqueeze(1)).squeeze(2)  # (n, B, 1) -> (n, B)
        critic_loss = chunk_critic_loss(q, target)
        self.critic.optimizer.zero_grad()
        critic_loss.backward()
        self.critic.optimizer.step()
        loss, info = self._actor_loss(data, obs_flat)
        self.actor.optimizer.zero_grad()
        loss.backward()
        self.actor.optimizer.step()
        polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        from sb3_ua2c.diagnostics import training_stats  # lazily: ``-m sb3_ua2c.diagnostics`` is __main__
        return {
            "critic_loss": critic_loss.item(),
            "actor_loss": loss.item(),
            "q_mean": q.mean().item(),
            **info,
            **training_stats(self, data, q, target),  # td_rmse, twin_gap (+ more every DIAGNOSTICS_INTERVAL)
        }

    def _next_values(self, obs_history: th.Tensor, action_history: th.Tensor) -> th.Tensor:
        """
        ``V(h) = max_q min_j Q̄_j(h, â^(q))`` (:func:`~sb3_ua2c.chunking.bootstrap_value`) over
        ``n_target_candidates`` chunks of the current actor.

        :param obs_history: ``(M, ℓ, obs_dim)``
        :param action_history: ``(M, ℓ, action_dim)``
        :return: shape ``(M,)``
        """
        m = obs_history.shape[0]
        cond = self.actor.condition(self.policy.flatten_history(obs_history, action_history))
        candidates = self.policy.sample_chunks(cond, self.n_target_candidates, self.target_flow_steps)
        next_q = self.critic_target(obs_history.reshape(m, -1), candidates.clamp(-1.0, 1.0))  # (n, M, Q)
        return bootstrap_value(next_q)  # (n, M, Q) -> (M,)

    def _actor_loss(
        self, data: ChunkReplaySamples, obs_flat: th.Tensor
    ) -> tuple[th.Tensor, dict[str, float]]:
        """
        Eq. 2 on the batch: flow matching on the sampled chunks and the value of the terminal estimate x̂1.
        """
        x1 = data.chunks
        x0 = th.randn_like(x1)
        tau = th.rand(x1.shape[0], device=x1.device)
        x_tau = interpolate(x0, x1, tau)
        cond = self.actor.condition(
            self.policy.flatten_history(data.observation_history, data.action_history)
        )
        velocity = self.actor(x_tau, tau, cond)
        x_hat = estimate_terminal(x_tau, tau, velocity)
        self.critic.requires_grad_(False)  # the value term of Eq. 2 does not train the critics
        try:  # x̂1 clipped to the bounds as FQL / Q-chunking clip before Q: a plain clamp, no gradient outside
            q_pi = self.critic(obs_flat, x_hat.clamp(-1.0, 1.0).unsqueeze(1))[:, :, 0]  # (n, B, 1) -> (n, B)
        finally:
            self.critic.requires_grad_(True)
        q = pessimistic_q(q_pi)  # (n, B) -> (B,)
        roughness = chunk_roughness(x_hat, self.policy.continuous_dims) if self.smooth_weight > 0.0 else None
        mask = data.chunk_mask  # the flow term skips the zeros that pad a window after an episode end
        return actor_loss(velocity, x0, x1, q, self.q_weight, roughness, self.smooth_weight, mask)

    def learn(
        self: SelfUA2C,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str = "UA2C",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfUA2C:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )


__all__ = ["UA2C"]
