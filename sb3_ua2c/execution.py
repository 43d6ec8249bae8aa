"""Adaptive chunk execution (paper §3.2, Eq. 7): the per-environment state machine shared by the training
rollouts and by the stateful ``predict`` (:class:`AdaptiveChunkExecutor`), and the window of recent
entropies from which ``entropy_threshold="auto"`` sets δ (:class:`EntropyWindow`).

The maths it applies (entropies, ``L_t``, the auto δ) are the pure functions of :mod:`sb3_ua2c.chunking`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.policies import BasePolicy

from sb3_ua2c.chunking import (
    auto_entropy_threshold,
    default_target_plan_length,
    entropy_growth_length,
    executable_prefix_length,
    quantile_entropy_thresholds,
)
from sb3_ua2c.config import ExecutionRule, check_arguments

#: candidates per history when :meth:`ExecutionRuleState.calibrate_entropy_thresholds` measures ``H_u``: the
#: estimator's SD (about 0.04 nats per action dim) is small next to the spread of ``H_u`` across states
CALIBRATION_SAMPLES = 256

#: state-dict keys of the execution rule (:meth:`ExecutionRuleState.load_state_dict`)
_RULE_STATE = ("entropy_window.", "calibrated_thresholds")

#: replannings (one row per env) whose entropies set δ under ``entropy_threshold="auto"``: short, because
#: the entropies drift as the policy learns and δ lags them by about half the window (docs/algorithm.md)
AUTO_THRESHOLD_WINDOW = 50



class EntropyWindow(th.nn.Module):
    """
    The entropies ``H_u`` of the last ``size`` replannings, one row per env (a ring), from which
    ``entropy_threshold="auto"`` sets δ (:func:`auto_entropy_threshold`). The rows and their count are
    buffers, so that ``save``/``load`` reproduce the δ of the saved model.

    :param chunk_size: ``k``
    :param size: rows kept (:data:`AUTO_THRESHOLD_WINDOW`)
    """

    def __init__(self, chunk_size: int, size: int = AUTO_THRESHOLD_WINDOW) -> None:
        super().__init__()
        self.register_buffer("rows", th.zeros(size, chunk_size))  # (size, k)
        self.register_buffer("count", th.zeros((), dtype=th.long))  # rows added so far

    def threshold(self, target: float, entropy: th.Tensor) -> th.Tensor:
        """
        δ for a replanning with entropies ``entropy`` ``(m, k)``: from the window, shape ``()``; while the
        window is empty, each row's own δ, shape ``(m, 1)`` (the shortest ``L_t >= target`` its entropies allow).
        """
        rows = self.rows[: min(int(self.count), self.rows.shape[0])]  # (n, k)
        if rows.shape[0]:
            return auto_entropy_threshold(rows, target)
        return auto_entropy_threshold(entropy.unsqueeze(-2), target).unsqueeze(-1)  # (m, 1, k) -> (m, 1)

    def add(self, entropy: th.Tensor) -> None:
        """Append the rows ``(m, k)`` of a replanning (the oldest rows are dropped past ``size``)."""
        size = self.rows.shape[0]
        new = entropy[-size:]  # (min(m, size), k)
        start = int(self.count) + entropy.shape[0] - new.shape[0]
        self.rows[(start + th.arange(new.shape[0], device=self.rows.device)) % size] = new.to(self.rows.dtype)
        self.count += entropy.shape[0]


class PlanResult(NamedTuple):
    """Output of one replanning for ``m`` environments."""

    #: selected chunks (clipped to [-1, 1]), shape ``(m, k, action_dim)``
    chunks: np.ndarray
    #: executable prefix lengths ``L_t`` (Eq. 7), shape ``(m,)``
    lengths: np.ndarray
    #: per-position entropies ``H_u``, shape ``(m, k)``
    entropy: np.ndarray


#: ``planner(observation_history (m, ℓ, obs_dim), action_history (m, ℓ, action_dim)) -> PlanResult``
Planner = Callable[[np.ndarray, np.ndarray], PlanResult]


class ChunkExecutorState(NamedTuple):
    """
    Recurrent state of the adaptive-chunk executor, as passed through ``predict(..., state=...)``.

    All arrays have the number of environments as first dim.
    """

    #: ``o_{t-ℓ+1:t}`` (the newest entry is the last observation seen), shape ``(n, ℓ, obs_dim)``
    observation_history: np.ndarray
    #: ``a_{t-ℓ:t-1}`` (zeros before the episode start), shape ``(n, ℓ, action_dim)``
    action_history: np.ndarray
    #: current plan (selected chunk), shape ``(n, k, action_dim)``
    plan: np.ndarray
    #: executable length ``L_t`` of the current plan, shape ``(n,)``
    plan_length: np.ndarray
    #: number of actions of the current plan already executed, shape ``(n,)``
    plan_position: np.ndarray
    #: under ``execution_rule="ensemble"``, the summed weights of the chunks that ``plan`` averages, per
    #: position, shape ``(n, k)`` (zeros under the other rules)
    ensemble_weight: np.ndarray


class ExecutorStep(NamedTuple):
    """What one executor step did, for every environment."""

    #: executed actions (normalised), shape ``(n, action_dim)``
    actions: np.ndarray
    #: whether a new plan started at this step, shape ``(n,)``
    new_plan: np.ndarray
    #: the current plans, shape ``(n, k, action_dim)``
    plans: np.ndarray
    #: ``L_t`` of the current plans, shape ``(n,)``
    plan_lengths: np.ndarray
    #: entropies of the plans made at this step (rows of other envs are NaN), shape ``(n, k)``
    entropy: np.ndarray


class AdaptiveChunkExecutor:
    """
    Per-environment adaptive chunk execution (Eq. 7): replan when the executable prefix of the current
    plan is used up or an episode starts, otherwise play the next action of the plan.

    The history window is padded at the episode start by repeating the first observation (past
    actions are zeros) and never crosses episodes. The same object drives the training rollouts and,
    rebuilt from a :class:`ChunkExecutorState`, ``predict``.

    :param n_envs: number of environments
    :param obs_dim: flattened observation size
    :param action_dim: action size
    :param chunk_size: chunk length ``k``
    :param history_len: history length ``ℓ``
    """

    def __init__(self, n_envs: int, obs_dim: int, action_dim: int, chunk_size: int, history_len: int) -> None:
        self.n_envs, self.obs_dim, self.action_dim = n_envs, obs_dim, action_dim
        self.chunk_size, self.history_len = chunk_size, history_len
        self.observation_history = np.zeros((n_envs, history_len, obs_dim), dtype=np.float32)
        self.action_history = np.zeros((n_envs, history_len, action_dim), dtype=np.float32)
        self.plan = np.zeros((n_envs, chunk_size, action_dim), dtype=np.float32)
        self.plan_length = np.zeros(n_envs, dtype=np.int64)
        self.plan_position = np.zeros(n_envs, dtype=np.int64)
        self.ensemble_weight = np.zeros((n_envs, chunk_size), dtype=np.float32)
        self._started = np.zeros(n_envs, dtype=bool)

    @property
    def state(self) -> ChunkExecutorState:
        """A copy of the recurrent state."""
        return ChunkExecutorState(
            self.observation_history.copy(),
            self.action_history.copy(),
            self.plan.copy(),
            self.plan_length.copy(),
            self.plan_position.copy(),
            self.ensemble_weight.copy(),
        )

    def load_state(self, state: ChunkExecutorState | tuple[np.ndarray, ...]) -> None:
        """
        Restore a state returned by :attr:`state` (copied; the argument is not modified).

        :param state: recurrent state of the same shapes
        """
        if len(state) != 6:
            raise ValueError(f"state must be a ChunkExecutorState (6 arrays), got a tuple of {len(state)}")
        obs_h, act_h, plan, plan_len, plan_pos, weight = (np.asarray(x) for x in state)
        expected = {
            "observation_history": (obs_h.shape, self.observation_history.shape),
            "action_history": (act_h.shape, self.action_history.shape),
            "plan": (plan.shape, self.plan.shape),
            "plan_length": (plan_len.shape, self.plan_length.shape),
            "plan_position": (plan_pos.shape, self.plan_position.shape),
            "ensemble_weight": (weight.shape, self.ensemble_weight.shape),
        }
        for name, (got, want) in expected.items():
            if got != want:
                raise ValueError(f"state.{name} has shape {got}, expected {want}")
        self.observation_history[:] = obs_h
        self.action_history[:] = act_h
        self.plan[:] = plan
        self.plan_length[:] = plan_len
        self.plan_position[:] = plan_pos
        self.ensemble_weight[:] = weight
        self._started[:] = True

    def reset(self, mask: np.ndarray, observations: np.ndarray) -> None:
        """
        Start new episodes for the environments in ``mask``: fill the history with their first
        observation, clear past actions and drop the current plan.

        :param mask: boolean, shape ``(n,)``
        :param observations: flattened observations, shape ``(n, obs_dim)``
        """
        self.observation_history[mask] = observations[mask, None, :]
        self.action_history[mask] = 0.0
        self.plan_position[mask] = 0
        self.plan_length[mask] = 0
        self.ensemble_weight[mask] = 0.0
        self._started[mask] = True

    def act(
        self,
        observations: np.ndarray,
        episode_start: np.ndarray,
        planner: Planner,
        noise: np.ndarray | None = None,
        ensemble_decay: float | None = None,
        ensemble_dims: Sequence[int] | None = None,
    ) -> ExecutorStep:
        """
        Observe ``o_t`` and return ``a_t`` for every environment, replanning where needed.

        :param observations: flattened current observations, shape ``(n, obs_dim)``
        :param episode_start: whether ``o_t`` is the first observation of an episode, shape ``(n,)``
        :param planner: see :data:`Planner`
        :param noise: optional exploration noise added to the executed actions (then clipped), ``(n, action_dim)``
        :param ensemble_decay: ``m`` of ``execution_rule="ensemble"`` (:meth:`ensemble`): a new plan is averaged
            with the earlier plans' actions for the same steps; ``None``: a new plan replaces the old one
        :param ensemble_dims: the action dims that are averaged (``None``: all); the others (categorical dims)
            take the new plan's value
        :return: the executed actions and what was (re)planned
        """
        observations = np.asarray(observations, dtype=np.float32).reshape(self.n_envs, self.obs_dim)
        start = np.asarray(episode_start, dtype=bool).reshape(self.n_envs) | ~self._started
        if start.any():
            self.reset(start, observations)
        cont = ~start
        if cont.any():
            # shift the window by one step: (n, ℓ, obs_dim), oldest first
            self.observation_history[cont, :-1] = self.observation_history[cont, 1:]
            self.observation_history[cont, -1] = observations[cont]
        replan = self.plan_position >= self.plan_length
        entropy = np.full((self.n_envs, self.chunk_size), np.nan, dtype=np.float32)
        if replan.any():
            idx = np.flatnonzero(replan)
            result = planner(self.observation_history[idx], self.action_history[idx])
            self.plan[idx] = result.chunks if ensemble_decay is None else self.ensemble(idx, result.chunks,
                                                                                       ensemble_decay, ensemble_dims)
            self.plan_length[idx] = result.lengths
            self.plan_position[idx] = 0
            entropy[idx] = result.entropy
        actions = self.plan[np.arange(self.n_envs), self.plan_position].copy()
        if noise is not None:
            actions = np.clip(actions + noise, -1.0, 1.0).astype(np.float32)
        self.plan_position += 1
        # push a_t into the action window
        self.action_history[:, :-1] = self.action_history[:, 1:]
        self.action_history[:, -1] = actions
        return ExecutorStep(actions, replan, self.plan.copy(), self.plan_length.copy(), entropy)


    def ensemble(self, idx: np.ndarray, chunks: np.ndarray, decay: float,
                 dims: Sequence[int] | None = None) -> np.ndarray:
        """
        Temporal ensembling (ACT, Zhao et al., 2023): the plans of rows ``idx`` become, position by position, the
        weighted mean of the new chunks and of what the earlier plans planned for the same steps. A plan made
        ``j`` steps before the new one weighs ``exp(decay * j)`` times as much (ACT's ``exp(-m i)``, ``i = 0`` the
        oldest); the summed weights are kept in ``ensemble_weight`` (see :class:`ChunkExecutorState`), so the
        mean is updated in place.

        :param idx: the replanned rows, shape ``(r,)``
        :param chunks: their new chunks, shape ``(r, k, action_dim)``
        :param decay: ``m >= 0``
        :param dims: the action dims averaged (``None``: all); the others keep the new chunks' values, since a
            mean of categorical codes (a lane change) falls between categories
        :return: the ensembled plans, shape ``(r, k, action_dim)``
        """
        k = self.chunk_size
        source = np.arange(k)[None, :] + self.plan_position[idx][:, None]  # (r, k): this step's position u in the old plan
        carried = source < k
        source = np.minimum(source, k - 1)
        old_weight = np.take_along_axis(self.ensemble_weight[idx], source, axis=1) * carried * math.exp(decay)  # (r, k)
        old_plan = np.take_along_axis(self.plan[idx], source[..., None], axis=1)  # (r, k, A)
        weight = old_weight + 1.0
        self.ensemble_weight[idx] = weight
        plans = ((old_plan * old_weight[..., None] + chunks) / weight[..., None]).astype(np.float32)
        if dims is not None:
            averaged = set(dims)
            kept = [d for d in range(chunks.shape[-1]) if d not in averaged]
            plans[..., kept] = chunks[..., kept]
        return plans


def length_shares(lengths: Sequence[int] | np.ndarray, chunk_size: int) -> list[float]:
    """The ``L_t`` histogram of executed plans: the share of plans with ``L_t = 1 .. k`` (``(k,)`` fractions
    summing to 1; zeros when there is no plan). Lengths above ``k`` are not counted."""
    counts = np.bincount(np.asarray(lengths, dtype=np.int64), minlength=chunk_size + 1)[1 : chunk_size + 1]
    return (counts / counts.sum()).tolist() if counts.sum() else [0.0] * chunk_size


def format_length_shares(shares: Sequence[float]) -> str:
    """An ``L_t`` histogram as whole percentages: ``[0.46, 0.28, 0.14, 0.05, 0.07] -> "46 28 14 5 7"``."""
    return " ".join(f"{100 * p:.0f}" for p in shares)


def resume_and_act(
    state: ChunkExecutorState | tuple[np.ndarray, ...] | None,
    episode_start: np.ndarray | None,
    observations: np.ndarray,
    chunk_size: int,
    history_len: int,
    action_dim: int,
    planner: Planner,
    ensemble_decay: float | None = None,
    ensemble_dims: Sequence[int] | None = None,
) -> tuple[ExecutorStep, ChunkExecutorState]:
    """
    One step of a stateful ``predict``: rebuild the executor from ``state``, act, return the new state.

    :param state: the state returned by the previous step (``None``: new episodes)
    :param episode_start: whether each observation starts an episode (``None``: every one without a
        state, none with one)
    :param observations: flattened observations, shape ``(n, obs_dim)``
    :param chunk_size: ``k``
    :param history_len: ``ℓ``
    :param action_dim: action size
    :param planner: see :data:`Planner`
    :param ensemble_decay: see :meth:`AdaptiveChunkExecutor.act`
    :param ensemble_dims: see :meth:`AdaptiveChunkExecutor.act`
    :return: what the executor did, and its state after the step
    """
    n_envs, obs_dim = observations.shape
    executor = AdaptiveChunkExecutor(n_envs, obs_dim, action_dim, chunk_size, history_len)
    if episode_start is None:
        episode_start = np.full(n_envs, state is None)
    if state is not None:
        executor.load_state(state)
    step = executor.act(observations, np.asarray(episode_start, dtype=bool).reshape(n_envs), planner,
                        ensemble_decay=ensemble_decay, ensemble_dims=ensemble_dims)
    return step, executor.state


class ExecutionRuleState(BasePolicy):
    """
    The execution rule's part of :class:`~sb3_ua2c.policies.UA2CPolicy` (not a policy of its own): the
    :class:`~sb3_ua2c.config.ExecutionRule` in force (``execution``), the state it keeps (the
    :class:`EntropyWindow` of ``entropy_threshold="auto"``, the calibrated thresholds ``delta_u`` of
    ``"quantile"``; buffers, saved with the policy) and the executed length ``L_t`` it gives a replanning
    (:meth:`plan_lengths`).
    """

    execution: ExecutionRule
    chunk_size: int
    entropy_window: EntropyWindow | None
    calibrated_thresholds: th.Tensor | None

    def _set_execution_rule(self, execution: ExecutionRule) -> None:
        """
        Set the execution rule (the implementation of :meth:`UA2C.set_execution_rule
        <sb3_ua2c.ua2c.UA2C.set_execution_rule>`, the one setter). ``entropy_threshold="auto"`` keeps the
        current window, or starts an empty one; ``"quantile"`` keeps calibrated thresholds, or starts
        uncalibrated ones.

        :param execution: the new rule (its ``target_plan_length`` must not exceed ``chunk_size``)
        """
        self._check_execution(execution)
        self.execution = execution
        self._follow_entropy_threshold()

    def _check_execution(self, execution: Any) -> None:
        if not isinstance(execution, ExecutionRule):
            raise ValueError(f"execution must be an ExecutionRule, got {execution!r}")
        execution.check_chunk_size(self.chunk_size)

    def _follow_entropy_threshold(self) -> None:
        """Keep ``entropy_window`` (or start an empty one) under ``"auto"``, and the calibrated
        thresholds under ``"quantile"``; drop what the rule does not use."""
        if not self.execution.auto:
            self.entropy_window = None
        elif self.entropy_window is None:
            self.entropy_window = EntropyWindow(self.chunk_size).to(self.device)
        if self.execution.rule != "quantile":
            self.calibrated_thresholds = None
        elif self.calibrated_thresholds is None:
            self.calibrated_thresholds = th.full((self.chunk_size,), math.nan, device=self.device)

    @property
    def needs_calibration(self) -> bool:
        """``execution_rule="quantile"`` without calibrated thresholds (:meth:`calibrate_entropy_thresholds`)."""
        return self.calibrated_thresholds is not None and bool(th.isnan(self.calibrated_thresholds).any())

    def calibrate_entropy_thresholds(
        self, obs_history: th.Tensor, action_history: th.Tensor, n_samples: int = CALIBRATION_SAMPLES,
        batch_size: int = 64,
    ) -> th.Tensor:
        """
        Calibrate ``execution_rule="quantile"``: measure ``H_u`` on the given histories with fresh noise and
        ``n_samples`` candidates each, and set ``calibrated_thresholds`` to their per-position
        ``entropy_quantile`` (:func:`~sb3_ua2c.chunking.quantile_entropy_thresholds`).

        :param obs_history: calibration histories, shape ``(n, ℓ, obs_dim)``
        :param action_history: their past actions, shape ``(n, ℓ, action_dim)``
        :param n_samples: candidates per history (more than ``n_candidates``: less estimator noise)
        :param batch_size: histories per sampling pass (memory only)
        :return: the measured ``H_u``, shape ``(n, k)``
        """
        if self.execution.rule != "quantile":
            raise ValueError(f"calibration applies to execution_rule='quantile', not {self.execution.rule!r}")
        check_arguments(n_candidates=n_samples)
        if obs_history.shape[0] < 2:
            raise ValueError(f"calibration needs at least 2 histories, got {obs_history.shape[0]}")
        with th.inference_mode():
            batches = range(0, obs_history.shape[0], batch_size)
            entropy = th.cat([self.sample_candidates(obs_history[i : i + batch_size],
                                                     action_history[i : i + batch_size], n_samples)[1]
                              for i in batches])  # (n, k)
        assert self.calibrated_thresholds is not None
        self.calibrated_thresholds.copy_(quantile_entropy_thresholds(entropy, self.execution.quantile))
        return entropy

    @property
    def ensemble_decay(self) -> float | None:
        """``m`` of the temporal ensembling under ``execution_rule="ensemble"``, else ``None``."""
        return self.execution.ensemble_decay if self.execution.rule == "ensemble" else None

    def current_entropy_threshold(self, entropy: th.Tensor | None = None) -> float | th.Tensor:
        """
        δ of the next replanning: ``entropy_threshold``, or under ``"auto"`` the δ whose mean ``L_t`` over
        ``entropy_window`` is ``target_plan_length`` (:func:`~sb3_ua2c.chunking.auto_entropy_threshold`).
        While the window is empty, each row of the replanning's entropies ``entropy`` ``(m, k)`` gets its
        own δ ``(m, 1)``, and without them the answer is ``nan``.
        """
        if self.entropy_window is None:
            return float(self.execution.entropy_threshold)
        if entropy is None and int(self.entropy_window.count) == 0:
            return math.nan
        target = self.execution.target_plan_length or default_target_plan_length(self.chunk_size)
        return self.entropy_window.threshold(target, entropy)

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        """``nn.Module.load_state_dict``; the execution rule's state (``entropy_window.*``,
        ``calibrated_thresholds``) follows this policy's rule, which a load may override: a checkpoint
        saved under another rule loads into an ``"auto"`` policy with an empty window and into a
        ``"quantile"`` policy uncalibrated, and a rule ignores the state of another."""
        own = {k: v for k, v in self.state_dict().items() if k.startswith(_RULE_STATE)}
        state_dict = {k: v for k, v in state_dict.items() if not k.startswith(_RULE_STATE) or k in own}
        return super().load_state_dict({**own, **state_dict}, strict=strict, assign=assign)

    def plan_lengths(self, entropy: th.Tensor) -> th.Tensor:
        """
        ``L_t`` of a replanning from its entropies ``H_u`` ``(m, k)`` by the execution rule: Eq. 7 with
        δ (``"threshold"``) or with the calibrated ``delta_u`` (``"quantile"``), or the growth rule
        (:func:`~sb3_ua2c.chunking.entropy_growth_length`), or one action (``"replan"``, ``"ensemble"``).
        Returns a long tensor ``(m,)`` in ``[1, k]``.
        """
        if self.execution.rule in ("replan", "ensemble"):
            return th.ones(entropy.shape[:1], dtype=th.long, device=entropy.device)
        if self.execution.rule == "growth":
            return entropy_growth_length(entropy, self.execution.growth)
        if self.execution.rule == "quantile":
            if self.needs_calibration:
                raise RuntimeError("execution_rule='quantile' acts once its thresholds are calibrated: call "
                                   "UA2C.calibrate_execution() (learn() does it from the replay buffer)")
            return executable_prefix_length(entropy, self.calibrated_thresholds)
        return executable_prefix_length(entropy, self.current_entropy_threshold(entropy))

