"""The policy of UA2C: the chunk actor (:mod:`sb3_ua2c.actors`) and the twin chunk critics (:mod:`sb3_ua2c.critics`)
with their Polyak targets, and the adaptive-chunk planner (Eq. 7) that ``predict`` runs.

Paper: "UA2C: Uncertainty-Aware Adaptive Action Chunking for Offline-to-Online Decision-Making in
Mixed Traffic", §2.3 and §3.
"""

from __future__ import annotations

import hashlib
import io
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.common.utils import get_device
from torch import nn

from sb3_ua2c.actor_objectives import ActorInputs, actor_history
from sb3_ua2c.actors import ACTORS, actor_class
from sb3_ua2c.chunking import (
    CRITIC_SELECTIONS,
    chunk_entropy,
    commit_through_switch,
    continuous_dims,
    select_candidates,
)
from sb3_ua2c.compat import legacy_critic_kwargs, legacy_execution_rule
from sb3_ua2c.config import ExecutionRule, check_arguments, check_spaces, normalize_discrete_dims
from sb3_ua2c.critics import critic_defaults, make_critic
from sb3_ua2c.execution import EntropyWindow, ExecutionRuleState, PlanResult, resume_and_act
from sb3_ua2c.exploration import ChunkSelector
from sb3_ua2c.targets import ChunkValue

#: key of the hash that seeds the candidate noise ``x_0`` of ``predict(..., deterministic=True)``
DETERMINISTIC_NOISE_KEY = b"sb3-ua2c"


def history_noise(obs_history: th.Tensor, action_history: th.Tensor, n_samples: int, chunk_size: int) -> th.Tensor:
    """
    The candidate noise ``x_0`` of ``predict(..., deterministic=True)``: for each history, a standard normal
    draw from a generator seeded with a hash (BLAKE2b) of the history's float32 bytes. The same history
    always gets the same noise, whatever the batch it is planned in; two histories get independent draws,
    so over the states of an episode the deterministic candidates spread as fresh noise's do (one draw
    shared by every state would bias every ``H_u`` by its own luck, by up to ±0.5 nats).

    :param obs_history: ``(m, ℓ, obs_dim)``
    :param action_history: ``(m, ℓ, action_dim)``
    :param n_samples: candidates ``S``
    :param chunk_size: ``k``
    :return: ``(m, S, k, action_dim)`` on the histories' device
    """
    m, action_dim = obs_history.shape[0], action_history.shape[-1]
    rows = th.cat([obs_history.reshape(m, -1), action_history.reshape(m, -1)], dim=1)
    rows = rows.detach().to("cpu", th.float32).numpy()
    noise = th.empty((m, n_samples, chunk_size, action_dim))
    for i in range(m):
        digest = hashlib.blake2b(rows[i].tobytes(), digest_size=8, key=DETERMINISTIC_NOISE_KEY).digest()
        generator = th.Generator().manual_seed(int.from_bytes(digest, "little") >> 1)
        noise[i] = th.randn((n_samples, chunk_size, action_dim), generator=generator)
    return noise.to(obs_history.device)


#: Hidden sizes of the velocity field when ``net_arch`` is not given (chosen on validation for its
#: speed: the 3 × 512 field of 2026-12-06 learnt no better at twice the cost; the paper's 128 × 2 is
#: :data:`sb3_ua2c.presets.PAPER`'s).
DEFAULT_NET_ARCH: tuple[int, ...] = (256, 256)
#: Candidates averaged into the executed chunk when ``n_elite`` is not given (chosen on validation;
#: the paper's best candidate, 1, is :data:`sb3_ua2c.presets.PAPER`'s), or all of them when fewer.
DEFAULT_N_ELITE = 8


def resolved_policy_defaults(policy_kwargs: dict[str, Any]) -> dict[str, Any]:
    """
    ``policy_kwargs`` with the arguments whose ``None`` stands for a default given that default:
    ``n_elite`` (:data:`DEFAULT_N_ELITE`), ``net_arch`` (:data:`DEFAULT_NET_ARCH`) and ``critic_kwargs``
    (the signature defaults of the ``critic_arch``'s class, :func:`~sb3_ua2c.critics.critic_defaults`).
    Used by :func:`sb3_ua2c.defaults.defaults`.

    :param policy_kwargs: the policy's arguments by name
    :return: a new dict
    """
    out = dict(policy_kwargs)
    if out.get("n_elite", 0) is None:
        out["n_elite"] = DEFAULT_N_ELITE
    if out.get("net_arch", 0) is None:
        out["net_arch"] = list(DEFAULT_NET_ARCH)
    if out.get("critic_kwargs", 0) is None and "critic_arch" in out:
        out["critic_kwargs"] = critic_defaults(out["critic_arch"])
    return out


class UA2CPolicy(ExecutionRuleState):
    """
    Policy of UA2C: flow-matching chunk actor, twin Transformer chunk critics (+ Polyak targets) and
    the adaptive-chunk planner (Eq. 7) used by ``predict``.

    The execution rule and its state are a part of it in :class:`~sb3_ua2c.execution.ExecutionRuleState`.
    The class stays over 300 lines for its 23 documented constructor arguments, each checked by name and
    saved by name (:meth:`_get_constructor_parameters`): no table looks them up at run time.

    :param observation_space: Box observation space
    :param action_space: Box action space
    :param lr_schedule: learning rate schedule
    :param chunk_size: ``k`` (required: UA2C passes its own)
    :param history_len: ``ℓ`` (required)
    :param flow_steps: Euler steps ``N`` when acting (required)
    :param n_candidates: chunks ``S`` sampled per replanning (required)
    :param execution: how ``L_t`` is set from the entropies ``H_u`` (:class:`~sb3_ua2c.config.ExecutionRule`;
        ``None`` = ``ExecutionRule()``, Eq. 7 with δ = 0); under ``entropy_threshold="auto"`` δ follows the
        entropies of the last replannings of training rollouts (:attr:`entropy_window`)
    :param discrete_action_dims: ``{action index: category values}`` of categorical action dims
        (:func:`~sb3_ua2c.config.normalize_discrete_dims`)
    :param discrete_entropy: ``H_u`` of Eq. 7 includes the categorical dims (``False``: the
        continuous dims alone; see :func:`~sb3_ua2c.chunking.chunk_entropy`)
    :param n_elite: candidates whose continuous actions are averaged into the executed chunk
        (``None``: :data:`DEFAULT_N_ELITE` = 8, chosen on validation, or ``n_candidates`` when fewer;
        1 = the best candidate, the paper's; see :func:`~sb3_ua2c.chunking.select_chunk`)
    :param selection: how a replanning turns its candidates into the executed chunk, one of
        :data:`~sb3_ua2c.chunking.SELECTIONS`: ``"elite"`` (the elite mean of ``n_elite`` by ``min_j Q_j``),
        ``"uncertainty"`` (weights ``softmax(mean_j Q_j / tau)``, ``tau`` the critics' disagreement:
        :func:`~sb3_ua2c.chunking.uncertainty_weights`), or without the critics ``"mean"`` (of all candidates),
        ``"sample"`` (one candidate) and ``"zero_noise"`` (the flow from ``x_0 = 0``)
    :param commit_discrete: extend ``L_t`` through the first switch of a categorical action in the
        selected chunk (see :func:`~sb3_ua2c.chunking.commit_through_switch`; not in the paper)
    :param net_arch: hidden sizes of the velocity-field MLP (and of the one-step policy's)
    :param actor_type: a key of :data:`~sb3_ua2c.actors.ACTORS`: ``"flow"`` (the paper's Eq. 2: candidates
        are Euler samples of the velocity field, which the value term trains) or ``"one_step"`` (QC-FQL's
        one-step policy, Li et al., 2025: an MLP ``mu(h, z)`` (:class:`~sb3_ua2c.actors.OneStepActor`)
        distilled from the flow and trained against Q; the flow learns by flow matching alone. Candidates,
        for acting and for the targets, are ``mu``'s: one network call per replanning; see :meth:`sample_chunks`)
    :param actor_past_actions: condition the actor on the past actions of the history (the paper's
        ``h_t``); ``False``: on the observations only, against copycat behaviour cloning (Wen et al.,
        NeurIPS 2020; de Haan et al., NeurIPS 2019). The critics never see past actions.
    :param critic_arch: a key of :data:`~sb3_ua2c.critics.CRITICS`: ``"transformer"`` (the paper's per-token
        critic, :class:`~sb3_ua2c.critics.ChunkCritics`) or ``"mlp"`` (an MLP over the flattened history
        and chunk, :class:`~sb3_ua2c.critics.MLPChunkCritics`)
    :param critic_kwargs: the own arguments of the ``critic_arch``'s class (``None``: its signature's
        defaults): ``embed_dim``, ``n_layers``, ``n_heads``, ``ff_dim`` of the Transformer; ``net_arch``,
        ``layer_norm`` of the MLP
    :param n_critics: number of critics
    :param activation_fn: activation class for actor and critics
    :param optimizer_class: optimizer class
    :param optimizer_kwargs: extra optimizer arguments (default for Adam/AdamW: ``{"fused": True}``)
    :param torch_compile: ``torch.compile`` the critics and the target critics (the first call with
        each input shape compiles, for seconds to a minute; results agree with eager mode to rounding,
        not bit for bit; see :meth:`compile_networks`)
    :param normalize_images: must be ``False``: observations are flattened as they are (SB3's
        argument, kept so that ``UA2CPolicy.load`` rebuilds the policy like SB3's policies)
    :param value_arch: the arguments (``net_arch``, ``layer_norm``) of the in-sample value ``V(h)``
        (:class:`~sb3_ua2c.targets.ChunkValue`, held as :attr:`value` with an optimizer of its own, built
        after the other networks); ``None``: no value network. Set by UA2C from its ``critic_target``
        (``"in_sample"``: the :class:`~sb3_ua2c.targets.InSampleTarget`'s), not a ``policy_kwargs`` key
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        chunk_size: int,
        history_len: int,
        flow_steps: int,
        n_candidates: int,
        execution: ExecutionRule | None = None,
        discrete_action_dims: Mapping[int, Sequence[float]] | None = None,
        discrete_entropy: bool = True,
        commit_discrete: bool = False,
        selection: str = "elite",
        n_elite: int | None = None,
        net_arch: list[int] | None = None,
        actor_type: str = "flow",
        actor_past_actions: bool = True,
        critic_arch: str = "transformer",
        critic_kwargs: dict[str, Any] | None = None,
        n_critics: int = 2,
        activation_fn: type[nn.Module] = nn.SiLU,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = False,
        torch_compile: bool = False,
        value_arch: dict[str, Any] | None = None,
    ) -> None:
        check_spaces(observation_space, action_space)
        if optimizer_kwargs is None and optimizer_class in (th.optim.Adam, th.optim.AdamW):
            # the fused kernel updates all parameters at once: ~6x faster than the per-tensor loop on CPU
            optimizer_kwargs = {"fused": True}
        super().__init__(
            observation_space,
            action_space,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            squash_output=True,
            normalize_images=normalize_images,
        )
        self.chunk_size = chunk_size
        self.history_len = history_len
        self.flow_steps = flow_steps
        self.n_candidates = n_candidates
        #: the execution rule (replaced only by :meth:`_set_execution_rule`, which checks it)
        self.execution = ExecutionRule() if execution is None else execution
        self.discrete_action_dims = discrete_action_dims
        self.discrete_entropy = discrete_entropy
        self.commit_discrete = commit_discrete
        self.selection = selection
        self.n_elite = min(DEFAULT_N_ELITE, n_candidates) if n_elite is None else n_elite
        self.net_arch = list(DEFAULT_NET_ARCH) if net_arch is None else net_arch
        self.actor_type = actor_type
        self.actor_past_actions = actor_past_actions
        self.critic_arch = critic_arch
        self.n_critics = n_critics
        self.activation_fn = activation_fn
        self.torch_compile = torch_compile
        check_arguments(
            chunk_size=chunk_size, history_len=history_len, flow_steps=flow_steps, n_candidates=n_candidates,
            discrete_action_dims=discrete_action_dims, discrete_entropy=discrete_entropy,
            commit_discrete=commit_discrete, selection=selection, n_elite=self.n_elite, net_arch=net_arch, actor_type=actor_type,
            actor_past_actions=actor_past_actions, critic_arch=critic_arch, critic_kwargs=critic_kwargs,
            n_critics=n_critics, activation_fn=activation_fn, optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs, normalize_images=normalize_images, torch_compile=torch_compile,
            value_arch=value_arch,
        )
        self._check_execution(self.execution)
        #: the critic class's own arguments, its signature's defaults filled in (saved with the policy)
        self.critic_kwargs = {**critic_defaults(critic_arch), **(critic_kwargs or {})}
        self.obs_dim = int(np.prod(observation_space.shape))
        self.action_dim = int(np.prod(action_space.shape))
        #: ``{action index: n_categories}`` of the categorical action dims, and the other (continuous) dims
        self.discrete_dims = normalize_discrete_dims(discrete_action_dims, self.action_dim)
        self.continuous_dims = continuous_dims(self.action_dim, self.discrete_dims)
        #: the entropies that set δ under ``entropy_threshold="auto"`` (``None`` for a numeric δ)
        self.entropy_window: EntropyWindow | None = None
        #: ``delta_u`` of ``execution_rule="quantile"``, shape ``(k,)`` (NaN until calibrated; a buffer,
        #: saved with the policy); ``None`` under the other rules
        self.register_buffer("calibrated_thresholds", None)
        self._follow_entropy_threshold()
        #: ``L_t`` and ``H_u`` of the last replanning done by ``predict`` (one row per env)
        self.last_plan_lengths: np.ndarray = np.zeros(0, dtype=np.int64)
        self.last_plan_entropy: np.ndarray = np.zeros((0, chunk_size), dtype=np.float32)
        self._build(lr_schedule)
        #: the in-sample value ``V(h)`` (``None`` without one), built after the other networks so that a
        #: policy without it draws the same random numbers as before it existed
        self.value: ChunkValue | None = None
        self.value_arch: dict[str, Any] | None = None
        self._set_value(value_arch, lr_schedule(1))
        if self.torch_compile:
            self.compile_networks()

    def _build(self, lr_schedule: Schedule) -> None:
        history_dim = self.history_len * (self.obs_dim + (self.action_dim if self.actor_past_actions else 0))
        actor_args = (history_dim, self.chunk_size, self.action_dim, list(self.net_arch), self.activation_fn)
        #: the velocity field of Eq. 2, learnt by flow matching under every ``actor_type``
        self.actor = ACTORS["flow"](*actor_args)
        self.critic, self.critic_target = self._make_critics(), self._make_critics()
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.requires_grad_(False)
        self.critic_target.train(False)
        kind = actor_class(self.actor_type)
        if kind.attribute != "actor":  # an actor of its own beside the flow (``one_step_actor``)
            self.add_module(kind.attribute, kind(*actor_args))
        # one optimizer for all actors: their objective is one sum over disjoint parameters
        actor_params = [p for net in self.actor_networks() for p in net.parameters()]
        self.actor.optimizer = self.optimizer_class(  # type: ignore[assignment]
            actor_params, lr=lr_schedule(1), **self.optimizer_kwargs
        )
        self.critic.optimizer = self.optimizer_class(  # type: ignore[assignment]
            self.critic.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def _set_value(self, value_arch: dict[str, Any] | None, learning_rate: float) -> None:
        """
        Build, keep or drop the value network (the implementation of
        :meth:`UA2C.set_critic_target <sb3_ua2c.ua2c.UA2C.set_critic_target>`): a ``V`` of the same
        ``value_arch`` is kept (and its optimizer), another replaces it, ``None`` removes it.

        :param value_arch: :class:`~sb3_ua2c.targets.ChunkValue`'s ``net_arch`` and ``layer_norm``, or ``None``
        :param learning_rate: the new optimizer's learning rate
        """
        if value_arch == self.value_arch and (value_arch is None) == (self.value is None):
            return
        self.value_arch = None if value_arch is None else dict(value_arch)
        if value_arch is None:
            self.value = None
            return
        value = ChunkValue(self.history_len * self.obs_dim, self.activation_fn, **value_arch).to(self.device)
        value.optimizer = self.optimizer_class(  # type: ignore[assignment]
            value.parameters(), lr=learning_rate, **self.optimizer_kwargs
        )
        self.value = value

    def _make_critics(self) -> nn.Module:
        """The twin critics of ``critic_arch``, ``(B, ℓ*obs_dim), (B, C, k, a) -> (n_critics, B, C)``."""
        return make_critic(self.critic_arch, self.history_len * self.obs_dim, self.chunk_size, self.action_dim,
                           self.n_critics, self.activation_fn, self.critic_kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()  # spaces and normalize_images
        return {
            **data,
            "lr_schedule": self._dummy_schedule,  # as SB3's policies: no learning rate to act with
            "chunk_size": self.chunk_size,
            "history_len": self.history_len,
            "flow_steps": self.flow_steps,
            "n_candidates": self.n_candidates,
            "execution": self.execution,
            "discrete_action_dims": self.discrete_action_dims,
            "discrete_entropy": self.discrete_entropy,
            "commit_discrete": self.commit_discrete,
            "selection": self.selection,
            "n_elite": self.n_elite,
            "net_arch": self.net_arch,
            "actor_type": self.actor_type,
            "actor_past_actions": self.actor_past_actions,
            "critic_arch": self.critic_arch,
            "critic_kwargs": self.critic_kwargs,
            "n_critics": self.n_critics,
            "activation_fn": self.activation_fn,
            "optimizer_class": self.optimizer_class,
            "optimizer_kwargs": self.optimizer_kwargs,
            "torch_compile": self.torch_compile,
            "value_arch": self.value_arch,
        }

    @classmethod
    def load(cls, path: str | io.BufferedIOBase | pathlib.Path, device: th.device | str = "auto") -> UA2CPolicy:
        """
        SB3's ``BasePolicy.load``; a policy saved before the execution rule became one
        :class:`~sb3_ua2c.config.ExecutionRule` (its five arguments saved one by one), or before the
        critics' arguments became ``critic_kwargs``, loads as well (:mod:`sb3_ua2c.compat`).

        :param path: the file :meth:`save` wrote
        :param device: device to load the policy on
        """
        device = get_device(device)
        saved = th.load(path, map_location=device, weights_only=False)
        data = legacy_critic_kwargs(saved["data"])
        data["execution"] = legacy_execution_rule(data, data.get("execution"))
        policy = cls(**data)
        policy.load_state_dict(saved["state_dict"])
        policy.to(device)
        return policy

    def compile_networks(self) -> None:
        """
        ``torch.compile`` (Inductor) the forward of the critics and of the target critics in place:
        parameters, state-dict keys and optimizers stay as they are. The critics are most of the cost
        of an update and of a replanning, in many small element-wise kernels that Inductor fuses; the
        flow sampler gains nothing measurable and is left in eager mode (see docs/benchmarks.md).

        The graphs are static: each input shape (the batch of the critic update, of the targets, of a
        replanning of ``m`` envs) and grad mode compiles once, for seconds to a minute. Past
        ``torch._dynamo.config.recompile_limit`` variants, torch runs new shapes eagerly. Fused kernels
        change the order of floating-point operations: the numbers agree with eager mode to rounding.
        """
        self.critic.compile(dynamic=False)
        self.critic_target.compile(dynamic=False)

    def _set_n_elite(self, n_elite: int) -> None:
        """Validate and set how many best candidates a replanning averages (the implementation of
        :meth:`UA2C.set_n_elite <sb3_ua2c.ua2c.UA2C.set_n_elite>`, the one setter)."""
        check_arguments(n_elite=n_elite, n_candidates=self.n_candidates)
        self.n_elite = n_elite

    def _set_selection(self, selection: str) -> None:
        """Validate and set how a replanning selects its chunk (the implementation of
        :meth:`UA2C.set_selection <sb3_ua2c.ua2c.UA2C.set_selection>`, the one setter)."""
        check_arguments(selection=selection, n_critics=self.n_critics)
        self.selection = selection

    def _set_flow_steps(self, flow_steps: int) -> None:
        """Validate and set the Euler steps when acting (the implementation of
        :meth:`UA2C.set_flow_steps <sb3_ua2c.ua2c.UA2C.set_flow_steps>`, the one setter)."""
        check_arguments(flow_steps=flow_steps)
        self.flow_steps = flow_steps

    def sample_candidates(
        self, obs_history: th.Tensor, action_history: th.Tensor, n_samples: int,
        generator: th.Generator | None = None, x0: th.Tensor | None = None,
    ) -> tuple[th.Tensor, th.Tensor]:
        """``n_samples`` candidate chunks per history (:meth:`sample_chunks`, ``flow_steps`` Euler steps),
        clipped to the action bounds as they would be executed, and their entropies ``H_u``
        (:func:`~sb3_ua2c.chunking.chunk_entropy`): ``(m, ℓ, ·)`` histories -> ``(m, S, k, A)`` and
        ``(m, k)``."""
        chunks = self.sample_chunks(obs_history, action_history, n_samples, self.flow_steps, generator, x0)
        clipped = chunks.clamp(-1.0, 1.0)
        return clipped, chunk_entropy(clipped, self.discrete_dims, discrete=self.discrete_entropy)

    def set_training_mode(self, mode: bool) -> None:
        for actor in self.actor_networks():
            actor.train(mode)
        self.critic.train(mode)
        if self.value is not None:
            self.value.train(mode)
        self.training = mode

    # ------------------------------------------------------------------ maths on tensors
    def value_trained_actor(self) -> nn.Module:
        """The network that acts and that the value term trains: the ``actor_type``'s (the velocity field
        itself for ``"flow"``, Eq. 2; ``one_step_actor`` for ``"one_step"``)."""
        return getattr(self, actor_class(self.actor_type).attribute)

    def actor_networks(self) -> list[nn.Module]:
        """The velocity field, and the ``actor_type``'s own network when it has one."""
        acting = self.value_trained_actor()
        return [self.actor] if acting is self.actor else [self.actor, acting]

    def actor_inputs(self) -> ActorInputs:
        """What the actor objectives read of the policy (:mod:`sb3_ua2c.actor_objectives`)."""
        return ActorInputs(self.actor, self.value_trained_actor(), self.critic, self.actor_past_actions,
                           self.continuous_dims, self.flow_steps)

    def flatten_history(self, obs_history: th.Tensor, action_history: th.Tensor) -> th.Tensor:
        """``(B, ℓ, obs_dim)`` and ``(B, ℓ, action_dim)`` -> the actors' input ``(B, history_dim)``
        (:func:`~sb3_ua2c.actor_objectives.actor_history`)."""
        return actor_history(obs_history, action_history, self.actor_past_actions)

    def condition(self, obs_history: th.Tensor, action_history: th.Tensor) -> th.Tensor:
        """
        The velocity field's history features: ``(B, ℓ, obs_dim), (B, ℓ, action_dim) -> (B, hidden)``.

        :param obs_history: ``(B, ℓ, obs_dim)``
        :param action_history: ``(B, ℓ, action_dim)``
        """
        return self.actor.condition(self.flatten_history(obs_history, action_history))

    def sample_chunks(
        self,
        obs_history: th.Tensor,
        action_history: th.Tensor,
        n_samples: int,
        n_steps: int,
        generator: th.Generator | None = None,
        x0: th.Tensor | None = None,
    ) -> th.Tensor:
        """
        The one path from histories to candidate chunks (acting, targets, diagnostics): ``n_samples``
        chunks per history from Gaussian noise, by the ``actor_type``'s ``sample``: ``n_steps`` Euler steps
        of the flow (``"flow"``) or one call of the one-step policy ``mu(h, z)`` (``"one_step"``;
        ``n_steps`` is not used).

        :param obs_history: ``(B, ℓ, obs_dim)``
        :param action_history: ``(B, ℓ, action_dim)``
        :param n_samples: candidates per history
        :param n_steps: Euler steps of the flow
        :param generator: optional random generator for the noise
        :param x0: the noise to start from, ``(B, n_samples, k, action_dim)`` (:func:`history_noise`);
            ``None``: independent Gaussian noise
        :return: unclipped chunks, shape ``(B, n_samples, k, action_dim)``
        """
        if x0 is None:
            shape = (obs_history.shape[0], n_samples, self.chunk_size, self.action_dim)
            x0 = th.randn(shape, generator=generator, device=obs_history.device, dtype=obs_history.dtype)
        return self.value_trained_actor().sample(self.flatten_history(obs_history, action_history), x0, n_steps)

    def plan_tensors(
        self,
        obs_history: th.Tensor,
        action_history: th.Tensor,
        generator: th.Generator | None = None,
        deterministic: bool = False,
        record_entropy: bool = False,
        selector: ChunkSelector | None = None,
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """
        One replanning: sample S chunks, measure the per-position entropy of the S samples (clipped to
        the action bounds: the actions that would be executed), turn them into the executed chunk by the
        ``selection`` (the critics score the candidates only for a selection that reads them) and set the
        executed length ``L_t`` by the execution rule (:meth:`plan_lengths`); ``commit_discrete`` then
        extends ``L_t`` through the first categorical switch.

        :param obs_history: shape ``(m, ℓ, obs_dim)``
        :param action_history: shape ``(m, ℓ, action_dim)``
        :param generator: optional random generator for the noise
        :param deterministic: start from each history's own noise (:func:`history_noise`) instead of fresh noise
        :param record_entropy: add the entropies to :attr:`entropy_window` (``entropy_threshold="auto"``
            only; training rollouts)
        :param selector: how the executed chunk is chosen among the candidates in training rollouts (UA2C's
            ``exploration``, :mod:`sb3_ua2c.exploration`); ``None``, or a selector that ``follows_policy``: the
            policy's own ``selection``, as ``predict`` always does
        :return: selected chunks (clipped) ``(m, k, action_dim)``, lengths ``(m,)``, entropy ``(m, k)``
        """
        m = obs_history.shape[0]
        if deterministic and m > 1:
            # one history at a time: its floats, and so the hash that seeds its noise, never depend on the batch
            rows = [self.plan_tensors(obs_history[i : i + 1], action_history[i : i + 1], None, True, record_entropy,
                                      selector) for i in range(m)]
            return tuple(th.cat(parts) for parts in zip(*rows, strict=True))  # type: ignore[return-value]
        s = self.n_candidates
        x0 = history_noise(obs_history, action_history, s, self.chunk_size) if deterministic else None
        # (m, S, k, A) clipped candidates and their (m, k) entropies
        clipped, entropy = self.sample_candidates(obs_history, action_history, s, generator, x0)
        lengths = self.plan_lengths(entropy)
        own = selector is None or getattr(selector, "follows_policy", False)
        q = None
        if not own or self.selection in CRITIC_SELECTIONS:
            q = self.critic(obs_history.reshape(m, -1), clipped)  # (n, m, S)
        if not own:
            chunks = selector.select(clipped, q, self.n_elite, self.discrete_dims)  # (m, k, A)
        elif self.selection == "zero_noise":  # the flow from x_0 = 0: one chunk of its own
            zeros = clipped.new_zeros((m, 1, self.chunk_size, self.action_dim))
            chunks = self.sample_chunks(obs_history, action_history, 1, self.flow_steps, x0=zeros)[:, 0].clamp(-1, 1)
        else:
            chunks = select_candidates(self.selection, clipped, q, self.n_elite, self.discrete_dims)  # (m, k, A)
        if record_entropy and self.entropy_window is not None:
            self.entropy_window.add(entropy)
        if self.commit_discrete:
            lengths = commit_through_switch(lengths, chunks, self.discrete_dims)
        return chunks, lengths, entropy

    def plan(
        self,
        obs_history: np.ndarray,
        action_history: np.ndarray,
        deterministic: bool = False,
        record_entropy: bool = False,
        selector: ChunkSelector | None = None,
    ) -> PlanResult:
        """
        NumPy front end of :meth:`plan_tensors` (a :data:`~sb3_ua2c.execution.Planner`).

        ``deterministic=True`` starts a history's S candidates from noise ``x_0`` seeded by the history
        itself (:func:`history_noise`), one history at a time: a row's plan is a function of its own
        history, bit for bit, whatever the batch it is planned in and its position there; the selection
        and the execution rule are unchanged. ``False``: fresh noise for every history, in one batch.
        ``record_entropy``, ``selector``: see :meth:`plan_tensors` (``predict`` never records: it does not
        change δ, and it keeps the elite mean).
        """
        with th.inference_mode():
            obs_t = th.as_tensor(obs_history, device=self.device, dtype=th.float32)
            act_t = th.as_tensor(action_history, device=self.device, dtype=th.float32)
            chunks, lengths, entropy = self.plan_tensors(obs_t, act_t, None, deterministic, record_entropy, selector)
        return PlanResult(chunks.cpu().numpy(), lengths.cpu().numpy(), entropy.cpu().numpy())

    # ------------------------------------------------------------------ SB3 interface
    def forward(self, obs: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        """First action of a plan made from a history holding only ``observation`` (episode start)."""
        assert isinstance(observation, th.Tensor)
        obs = observation.reshape(observation.shape[0], 1, -1).expand(-1, self.history_len, -1)
        act = th.zeros(obs.shape[0], self.history_len, self.action_dim, device=obs.device)
        chunks, _, _ = self.plan_tensors(obs.float(), act, deterministic=deterministic)
        return chunks[:, 0]

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        One action per environment step; ``state`` carries the history window and the remaining chunk
        (a :class:`~sb3_ua2c.execution.ChunkExecutorState`), so ``evaluate_policy``, ``EvalCallback``
        and rl-zoo's ``enjoy`` replan only when the executable prefix is used up or an episode starts.

        :param observation: observation(s)
        :param state: state returned by the previous call (``None`` = new episodes)
        :param episode_start: whether each observation starts an episode
        :param deterministic: noise seeded by each history (:func:`history_noise`: same history -> same
            plan, whatever the other rows) instead of fresh noise
        :return: actions in the env's action space and the next state
        """
        if self.actor.training or self.critic.training:
            # Module.train() walks every submodule (~0.4 ms): only when a mode switch is needed
            self.set_training_mode(False)
        if isinstance(observation, dict):
            raise ValueError("UA2C supports Box observation spaces only, got a dict observation")
        obs = np.asarray(observation, dtype=np.float32)
        vectorized = obs.shape != self.observation_space.shape
        obs = obs.reshape(-1, self.obs_dim)
        n_envs = obs.shape[0]
        step, new_state = resume_and_act(
            state, episode_start, obs, self.chunk_size, self.history_len, self.action_dim,
            lambda o, a: self.plan(o, a, deterministic), self.ensemble_decay, self.continuous_dims,
        )
        if step.new_plan.any():
            if self.last_plan_lengths.shape != (n_envs,):
                self.last_plan_lengths = np.zeros(n_envs, dtype=np.int64)
                self.last_plan_entropy = np.zeros((n_envs, self.chunk_size), dtype=np.float32)
            self.last_plan_lengths[step.new_plan] = step.plan_lengths[step.new_plan]
            self.last_plan_entropy[step.new_plan] = step.entropy[step.new_plan]
        actions = self.unscale_action(step.actions).reshape((-1, *self.action_space.shape))
        if not vectorized:
            actions = actions.squeeze(axis=0)
        return actions, new_state


MlpPolicy = UA2CPolicy
