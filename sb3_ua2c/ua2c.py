"""UA2C as a Stable-Baselines3 off-policy algorithm: rollouts with adaptive chunk execution, chunk-level
training (Eq. 2, 3, 4, 8), offline episodes and Phase-1 pre-training from the buffer.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §3.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import polyak_update

from sb3_ua2c.actor_objectives import ActorWeights
from sb3_ua2c.buffers import ChunkReplayBuffer, ChunkReplaySamples
from sb3_ua2c.checkpoints import Checkpoints
from sb3_ua2c.chunking import chunk_critic_loss, chunk_target
from sb3_ua2c.compat import legacy_critic_kwargs, legacy_execution_rule, reject_legacy_policy_kwargs
from sb3_ua2c.config import (
    ExecutionRule,
    check_arguments,
    check_policy_kwargs,
    check_spaces,
    make_execution_rule,
)
from sb3_ua2c.diagnostics import training_stats
from sb3_ua2c.execution import AdaptiveChunkExecutor
from sb3_ua2c.offline_training import OfflineTraining
from sb3_ua2c.options import TrainingOptions
from sb3_ua2c.policies import MlpPolicy, UA2CPolicy
from sb3_ua2c.rollouts import ChunkRollouts

SelfUA2C = TypeVar("SelfUA2C", bound="UA2C")


class UA2C(ChunkRollouts, OfflineTraining, TrainingOptions, Checkpoints):
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

    The class is UA2C's constructor, setup, setters and training step; its rollouts
    (:class:`~sb3_ua2c.rollouts.ChunkRollouts`), offline data and Phase 1
    (:class:`~sb3_ua2c.offline_training.OfflineTraining`), the options beyond the paper
    (:class:`~sb3_ua2c.options.TrainingOptions`) and checkpoints
    (:class:`~sb3_ua2c.checkpoints.Checkpoints`) are parts of it in modules of their own. It stays
    over 300 lines for its 47 documented constructor arguments (SB3's and UA2C's).

    :param policy: the policy model to use (``"MlpPolicy"`` or :class:`UA2CPolicy`)
    :param env: the environment to learn from (if registered in Gym, can be str)
    :param learning_rate: learning rate for Adam (actor and critics), constant or schedule
    :param buffer_size: size of the online replay ring (steps per env)
    :param learning_starts: steps of uniform random chunks before learning starts
    :param batch_size: minibatch size of each gradient step (chunk transitions)
    :param tau: Polyak coefficient of the target critics
    :param gamma: discount factor (per environment step; a chunk of length ``L`` is discounted by ``gamma^L``)
    :param train_freq: update the model every ``train_freq`` steps (int or ``(n, "step"|"episode")``)
    :param gradient_steps: gradient steps after each rollout (default 1: one per env step, SAC's); ``-1``
        (the paper's) = one per plan started
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
        of a replanning's candidates: an :class:`~sb3_ua2c.config.ExecutionRule`, or the name of its
        ``rule``: ``"threshold"`` (Eq. 7), ``"quantile"`` or ``"growth"`` (not in the paper). A name and the
        next four arguments make up the policy's :class:`~sb3_ua2c.config.ExecutionRule` (:attr:`execution`;
        its fields and their defaults are documented there, ``None`` here stands for them; given with an
        ``ExecutionRule``, any of the four raises a ``ValueError``); ``learn`` calibrates ``"quantile"``
        from the replay buffer when needed (:meth:`calibrate_execution`)
    :param entropy_threshold: ``delta`` of Eq. 7 in nats (``math.inf`` = the whole chunk), or ``"auto"``
    :param target_plan_length: with ``entropy_threshold="auto"`` only: the target mean ``L_t`` in ``[1, k]``
    :param entropy_quantile: with ``execution_rule="quantile"`` only: ``q`` in ``[0, 1]``
    :param entropy_growth: with ``execution_rule="growth"`` only: ``c`` in nats above ``H_1``
    :param q_weight: ``lambda``, weight of the value term in Eq. 2 (default 0.3, chosen on validation;
        the paper's: 1.0)
    :param smooth_weight: ``mu``, weight of an in-chunk smoothness term added to Eq. 2 (not in the
        paper; 0 = Eq. 2): ``mu`` times the mean squared step change of the continuous actions
        inside the actor's terminal estimate x̂1. It does not act on ``chunk_size=1``.
    :param past_action_dropout: ``p`` of history dropout in training (not in the paper; 0 = the paper):
        the past actions of each sample's history are zeroed with probability ``p`` in the actor's
        objective (flow matching, value term, distillation), against copycat behaviour cloning from
        histories (Wen et al., NeurIPS 2020, "Fighting Copycat Agents in Behavioral Cloning from
        Observation Histories"; de Haan et al., NeurIPS 2019). Acting and the targets use the real
        past actions. The mask comes from torch's global random stream (seeded runs reproduce);
        ``p = 0`` draws nothing. To drop the past actions from the actor's input altogether, see
        ``policy_kwargs["actor_past_actions"]``
    :param normalize_q: divide the value term by the (detached) batch mean ``|Q|`` (``True``, TD3+BC's
        normalisation, Fujimoto & Gu, 2021); ``False``: the raw ``λ Q`` of FQL (Park et al., 2025) and
        QC-FQL (Li et al., 2025; ``normalize_q_loss=False``), so ``λ`` is in reward units
    :param distill_weight: ``alpha`` of QC-FQL's one-step policy (``policy_kwargs["actor_type"] =
        "one_step"`` only; QC-FQL's ``alpha = 100``): weight of the distance of ``mu(h, z)`` to the
        flow's sample from the same ``z`` (:func:`~sb3_ua2c.flow.one_step_actor_loss`)
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
    :param critic_target: the bootstrap ``V(h_{t+L})`` of the critics' targets, a key of
        :data:`~sb3_ua2c.targets.CRITIC_TARGETS`: ``"candidates"`` (default, Eq. 4 / 8: the max over
        ``n_target_candidates`` actor chunks) or ``"in_sample"`` (not in the paper; IQL, Kostrikov et al.,
        ICLR 2022, as IFQL / SHARSA, Park et al., 2025, over chunks as Q-chunking's backup, Li et al.,
        2025): a value network ``V(h)`` (the policy's ``value``) fitted by expectile regression to
        ``min_j Q̄_j`` of the data's own chunks, so no target queries a chunk the data lacks and no
        candidate is sampled (:class:`~sb3_ua2c.targets.InSampleTarget`). The target network keeps its
        SB3 name, ``model.critic_target``; this argument is ``model.critic_target_name``. Change it with
        :meth:`set_critic_target` (e.g. after Phase 1) or ``UA2C.load(path, critic_target=...)``
    :param critic_target_kwargs: the own arguments of the ``critic_target``'s class (``None``: its
        signature's defaults): ``expectile`` (0.7, d3rlpy's IQL), ``net_arch``, ``layer_norm`` of ``V``
        for ``"in_sample"``; none for ``"candidates"``
    :param actor_extraction: how the actor is extracted from the critics, a key of
        :data:`~sb3_ua2c.extraction.ACTOR_EXTRACTIONS`: ``"value_term"`` (default, Eq. 2's ``-λ Q(x̂1)``,
        or QC-FQL's objective for ``actor_type="one_step"``) or ``"awr"`` (not in the paper; AWR, Peng et
        al., 2019, as IQL's extraction): the flow-matching error of each data chunk weighted by
        ``min(exp(β (min_j Q̄_j(h, a) - V(h))), w_max)`` and no value term
        (:class:`~sb3_ua2c.extraction.AdvantageWeightedExtraction`). ``"awr"`` needs
        ``critic_target="in_sample"`` (its ``V``) and ``actor_type="flow"``: otherwise a ``ValueError``
        naming ``actor_extraction``
    :param actor_extraction_kwargs: the own arguments of the ``actor_extraction``'s class (``None``: its
        defaults): ``temperature`` β (3.0) and ``max_weight`` (100, both d3rlpy's IQL) for ``"awr"``
    :param exploration: which candidate a replanning of ``learn()``'s rollouts executes, a key of
        :data:`~sb3_ua2c.exploration.EXPLORATIONS`: ``"softmax"`` (default; not in the paper; IDQL's
        resampling, Hansen-Estruch et al., 2023): one candidate drawn with probability
        ``∝ exp(min_j Q_j / T)`` from torch's global random stream, or ``"plan"`` (the paper's, and the
        default until 2026-12-07): as ``predict``, the elite mean. ``predict`` and ``evaluate_policy``
        keep the elite mean; ``L_t`` follows the entropies as before
    :param exploration_kwargs: the own arguments of the ``exploration``'s class (``None``: its
        defaults): ``temperature`` ``T`` (1.0, in the critics' reward units) for ``"softmax"``
    :param stats_window_size: window size for the rollout logging
    :param tensorboard_log: the log location for tensorboard (if None, no logging)
    :param policy_kwargs: additional arguments of the policy (``net_arch``, ``actor_type``,
        ``actor_past_actions``, ``n_elite``, ``critic_arch``, ``critic_kwargs``, ``n_critics``,
        ``activation_fn``, ``optimizer_class``, ``optimizer_kwargs``, ``torch_compile``: see :class:`UA2CPolicy`)
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
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | type[ChunkReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        chunk_size: int = 5,
        history_len: int = 4,
        flow_steps: int = 5,
        target_flow_steps: int = 2,
        n_candidates: int = 32,
        n_target_candidates: int = 2,
        execution_rule: str | ExecutionRule | None = None,
        entropy_threshold: float | str | None = None,
        target_plan_length: float | None = None,
        entropy_quantile: float | None = None,
        entropy_growth: float | None = None,
        q_weight: float = 0.3,
        smooth_weight: float = 0.0,
        past_action_dropout: float = 0.0,
        normalize_q: bool = True,
        distill_weight: float = 100.0,
        discrete_entropy: bool = True,
        commit_discrete: bool = False,
        discrete_action_dims: Mapping[int, Sequence[float]] | None = None,
        offline_ratio: float = 0.5,
        online_targets: str = "auto",
        critic_target: str = "candidates",
        critic_target_kwargs: dict[str, Any] | None = None,
        actor_extraction: str = "value_term",
        actor_extraction_kwargs: dict[str, Any] | None = None,
        exploration: str = "softmax",
        exploration_kwargs: dict[str, Any] | None = None,
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
        reject_legacy_policy_kwargs(policy_kwargs)
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
        #: the execution rule the policy acts with (change it with :meth:`set_execution_rule`)
        self.execution = make_execution_rule(
            execution_rule,
            entropy_threshold=entropy_threshold,
            target_plan_length=target_plan_length,
            entropy_quantile=entropy_quantile,
            entropy_growth=entropy_growth,
        )
        self.q_weight = q_weight
        self.smooth_weight = smooth_weight
        self.past_action_dropout = past_action_dropout
        self.normalize_q = normalize_q
        self.distill_weight = distill_weight
        self.discrete_entropy = discrete_entropy
        self.commit_discrete = commit_discrete
        self.discrete_action_dims = discrete_action_dims
        self.offline_ratio = offline_ratio
        self.online_targets = online_targets
        #: the name of the critics' bootstrap (``self.critic_target`` is the target critics, SB3's name)
        self.critic_target_name = critic_target
        self.critic_target_kwargs = critic_target_kwargs
        self.actor_extraction = actor_extraction
        self.actor_extraction_kwargs = actor_extraction_kwargs
        self.exploration = exploration
        self.exploration_kwargs = exploration_kwargs
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ setup
    def _setup_model(self) -> None:
        # a checkpoint of the earlier layout, or load(path, entropy_threshold=...): into the one rule
        self.execution = legacy_execution_rule(self.__dict__, self.execution)
        self.policy_kwargs = legacy_critic_kwargs(self.policy_kwargs) or {}
        # the policy and the replay buffer check the arguments they take; UA2C checks the others
        check_arguments(
            learning_rate=self.learning_rate,
            learning_starts=self.learning_starts,
            batch_size=self.batch_size,
            tau=self.tau,
            gamma=self.gamma,
            target_flow_steps=self.target_flow_steps,
            n_target_candidates=self.n_target_candidates,
            q_weight=self.q_weight,
            smooth_weight=self.smooth_weight,
            past_action_dropout=self.past_action_dropout,
            normalize_q=self.normalize_q,
            distill_weight=self.distill_weight,
        )
        check_spaces(self.observation_space, self.action_space)
        check_policy_kwargs(self.policy_kwargs, self.policy_class, UA2C)
        self._configure_options(with_policy=False)
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space,
            self.action_space,
            self.lr_schedule,
            chunk_size=self.chunk_size,
            history_len=self.history_len,
            flow_steps=self.flow_steps,
            n_candidates=self.n_candidates,
            execution=self.execution,
            discrete_action_dims=self.discrete_action_dims,
            discrete_entropy=self.discrete_entropy,
            commit_discrete=self.commit_discrete,
            value_arch=self._target_rule.value_arch,
            **self.policy_kwargs,
        )
        self.policy = self.policy.to(self.device)
        check_arguments(actor_extraction=self.actor_extraction, actor_type=self.policy.actor_type)
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

    def set_execution_rule(self, execution: ExecutionRule) -> None:
        """
        Change the execution rule (execution only; the losses do not depend on it), e.g. to evaluate one
        checkpoint under several rules: ``model.set_execution_rule(ExecutionRule("growth", entropy_growth=0.2))``
        or ``dataclasses.replace(model.execution, entropy_threshold=math.inf)``. ``"quantile"`` keeps
        calibrated thresholds (or needs :meth:`calibrate_execution`), ``"auto"`` keeps the entropy window
        (or starts an empty one). Kept by :meth:`save`. This is the one setter of the rule: ``load``'s
        overrides and the evaluation helpers call it.

        :param execution: the new rule (:class:`~sb3_ua2c.config.ExecutionRule`)
        """
        self.policy._set_execution_rule(execution)
        self.execution = execution

    def set_n_elite(self, n_elite: int) -> None:
        """
        Change how many best candidates a replanning averages (``policy_kwargs["n_elite"]``, see
        :func:`~sb3_ua2c.chunking.select_chunk`; execution only, kept by :meth:`save`).

        :param n_elite: in ``[1, n_candidates]``
        """
        self.policy._set_n_elite(n_elite)
        # a new dict: ``policy_kwargs`` may be the caller's own (SB3 keeps the reference)
        self.policy_kwargs = {**self.policy_kwargs, "n_elite": self.policy.n_elite}

    def set_selection(self, selection: str) -> None:
        """
        Change how a replanning turns its candidates into the executed chunk (``policy_kwargs["selection"]``,
        one of :data:`~sb3_ua2c.chunking.SELECTIONS`, see :func:`~sb3_ua2c.chunking.select_candidates`;
        acting only, kept by :meth:`save`): e.g. evaluate one checkpoint under several selections.

        :param selection: ``"elite"``, ``"uncertainty"``, ``"mean"``, ``"sample"`` or ``"zero_noise"``
        """
        self.policy._set_selection(selection)
        self.policy_kwargs = {**self.policy_kwargs, "selection": self.policy.selection}

    def set_flow_steps(self, flow_steps: int) -> None:
        """
        Change the Euler steps ``N`` of the flow sampler when acting (execution only: the losses use
        the one-step estimate of Eq. 2 and ``target_flow_steps``; kept by :meth:`save`).

        :param flow_steps: >= 1
        """
        self.policy._set_flow_steps(flow_steps)
        self.flow_steps = flow_steps

    # ------------------------------------------------------------------ training
    def train(self, gradient_steps: int, batch_size: int) -> None:  # type: ignore[override]
        """
        ``gradient_steps`` updates of the critics (Eq. 3 with targets Eq. 4 / 8), the actor (Eq. 2)
        and the Polyak targets, each on ``batch_size`` chunk transitions.
        """
        n_online, n_offline = self.replay_buffer.n_samples()
        if n_online + n_offline == 0:
            return
        self.policy.set_training_mode(True)
        value = [] if self.policy.value is None else [self.policy.value.optimizer]
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer, *value])
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
        """One update of the value network (``critic_target="in_sample"`` only), the critics (Eq. 3 with
        the target of Eq. 4 / 8), the actor (Eq. 2 or ``actor_extraction``) and the targets."""
        obs_flat = data.observation_history.flatten(1)  # (B, ℓ, obs_dim) -> (B, ℓ*obs_dim)
        value_info = self._value_step(data)
        with th.no_grad():
            next_value = self._next_values(data.next_observation_history, data.next_action_history)
            target = chunk_target(data.rewards, data.horizons, data.bootstrap, next_value, self.gamma)  # (B,)
        q = self.critic(obs_flat, data.chunks.unsqueeze(1)).squeeze(2)  # (n, B, 1) -> (n, B)
        critic_loss = chunk_critic_loss(q, target)
        self.critic.optimizer.zero_grad()
        critic_loss.backward()
        self.critic.optimizer.step()
        loss, info = self._actor_loss(data)
        self.actor.optimizer.zero_grad()
        loss.backward()
        self.actor.optimizer.step()
        polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        return {
            "critic_loss": critic_loss.item(),
            "actor_loss": loss.item(),
            "q_mean": q.mean().item(),
            **value_info,
            **info,
            **training_stats(self, data, q, target),  # td_rmse, twin_gap (+ more every DIAGNOSTICS_INTERVAL)
        }

    def _value_step(self, data: ChunkReplaySamples) -> dict[str, float]:
        """One update of the ``critic_target``'s value network on the batch, if it has one (``"in_sample"``:
        expectile regression, :class:`~sb3_ua2c.targets.InSampleTarget`); ``{}`` and nothing drawn otherwise."""
        out = self._target_rule.value_loss(self._target_inputs(), data)
        if out is None:
            return {}
        loss, info = out
        optimizer = self.policy.value.optimizer
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        return info

    def _next_values(self, obs_history: th.Tensor, action_history: th.Tensor) -> th.Tensor:
        """
        The bootstrap ``V(h)`` of the ``critic_target`` (:mod:`sb3_ua2c.targets`): ``max_q min_j Q̄_j(h, â^(q))``
        over ``n_target_candidates`` chunks of the current actor (``"candidates"``, Eq. 4 / 8), or the
        in-sample value network (``"in_sample"``).

        :param obs_history: ``(M, ℓ, obs_dim)``
        :param action_history: ``(M, ℓ, action_dim)``
        :return: shape ``(M,)``
        """
        return self._target_rule.next_value(self._target_inputs(), obs_history, action_history)

    def _actor_loss(self, data: ChunkReplaySamples) -> tuple[th.Tensor, dict[str, float]]:
        """The actor objective of the ``actor_extraction`` on the batch (:mod:`sb3_ua2c.extraction`): the
        policy's ``actor_type``'s (Eq. 2 or QC-FQL's one-step policy), or advantage-weighted flow matching."""
        objective = self._extraction_rule.objective(self.policy, data, self.actor_weights())
        return objective.loss, objective.info

    def actor_weights(self, q_weight: float | None = None) -> ActorWeights:
        """
        The weights of the actor objective (:class:`~sb3_ua2c.actor_objectives.ActorWeights`).

        :param q_weight: ``λ`` (``None``: the model's ``q_weight``)
        """
        weight = self.q_weight if q_weight is None else q_weight
        return ActorWeights(weight, self.smooth_weight, self.normalize_q, self.distill_weight, self.past_action_dropout)

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
