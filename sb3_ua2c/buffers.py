"""Chunk replay buffer of UA2C: per-step transitions plus, per online plan, the selected chunk and the
executed length ``L_t``; an offline part holds whole logged episodes sampled as k-step windows.

One sampling path serves both parts: every sample is a window starting at step ``t`` with a horizon
``L`` (``min(k, steps to the episode end)`` for offline windows, the executed length for online
plans), a chunk of ``k`` actions (the executed actions for ``u < L``; the unexecuted tail of the plan
online, zeros offline), the ``k`` rewards (masked at ``u >= L``), a bootstrap mask (0 iff the episode
terminated at the window's last step) and the histories at ``t`` and ``t + L``.

``online_targets="window"`` (not in the paper) samples the online steps like the offline ones: every
executed step starts a k-step window of the actions executed next, across plan boundaries (Eq. 4),
instead of one sample per plan with its executed prefix (Eq. 8). ``online_targets="auto"`` chooses
when the first online step is stored: Eq. 8 if the batches mix in offline episodes (offline-to-online,
the paper's setting), windows otherwise (online-only training), the better of the two in each setting
as measured (docs/benchmarks.md).

"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sb3_ua2c.config import check_arguments
from sb3_ua2c.offline import Episode


class ChunkReplaySamples(NamedTuple):
    """A batch of chunk transitions (tensors)."""

    #: ``o_{t-ℓ+1:t}``, shape ``(B, ℓ, obs_dim)``
    observation_history: th.Tensor
    #: ``a_{t-ℓ:t-1}``, shape ``(B, ℓ, action_dim)``
    action_history: th.Tensor
    #: ``a_{t:t+k-1}`` (normalised), shape ``(B, k, action_dim)``
    chunks: th.Tensor
    #: ``r_{t:t+k-1}``, zero at ``u >= L``, shape ``(B, k)``
    rewards: th.Tensor
    #: ``L``, shape ``(B,)``
    horizons: th.Tensor
    #: 1 to bootstrap from ``h_{t+L}``, 0 if the episode terminated inside the window, shape ``(B,)``
    bootstrap: th.Tensor
    #: ``o_{t+L-ℓ+1:t+L}``, shape ``(B, ℓ, obs_dim)``
    next_observation_history: th.Tensor
    #: ``a_{t+L-ℓ:t+L-1}``, shape ``(B, ℓ, action_dim)``
    next_action_history: th.Tensor
    #: 1 where ``chunks`` holds an action, 0 on the zero padding after an episode's end, shape ``(B, k)``:
    #: ``u < L`` for windows (offline, ``online_targets="window"``); every ``u`` for plans (Eq. 8), whose
    #: unexecuted tail is the selected plan, the chunk the critic is trained on (``None`` = all valid)
    chunk_mask: th.Tensor | None = None


def episode_arrays(ep: Episode, index: int, obs_dim: int, action_dim: int) -> dict[str, np.ndarray]:
    """
    The checked per-step arrays of a logged episode, named as the fields of the buffer's storage.

    :param ep: the episode (actions normalised to [-1, 1])
    :param index: its position in the added sequence (named in the errors)
    :param obs_dim: flattened observation size
    :param action_dim: action size
    :return: ``obs``, ``next_obs`` ``(T, obs_dim)``, ``actions`` ``(T, action_dim)``, ``rewards``,
        ``terminated`` ``(T,)``
    :raises ValueError: naming the episode and the field, on an empty episode, a shape that does not
        fit, actions outside [-1, 1] or an episode end before the last step
    """
    actions = np.asarray(ep.actions, dtype=np.float32)
    t_len = actions.shape[0]
    if t_len == 0:
        raise ValueError(f"offline episode {index} is empty")
    obs = np.asarray(ep.observations, dtype=np.float32)
    if ep.next_observations is None:  # (T+1, ...) rows, checked by the Episode
        next_obs, obs = obs[1:], obs[:-1]
    else:
        next_obs = np.asarray(ep.next_observations, dtype=np.float32)
    fields = {
        "observations": (obs.reshape(obs.shape[0], -1).shape, (t_len, obs_dim)),
        "next_observations": (next_obs.reshape(next_obs.shape[0], -1).shape, (t_len, obs_dim)),
        "actions": (actions.reshape(t_len, -1).shape, (t_len, action_dim)),
        "rewards": (np.shape(ep.rewards), (t_len,)),
        "terminations": (np.shape(ep.terminations), (t_len,)),
        "truncations": (np.shape(ep.truncations), (t_len,)),
    }
    for name, (got, want) in fields.items():
        if got != want:
            raise ValueError(f"offline episode {index}: {name} has shape {got}, expected {want}")
    if np.abs(actions).max() > 1.0 + 1e-6:
        raise ValueError(f"offline episode {index}: actions must be normalised to [-1, 1]")
    term = np.asarray(ep.terminations, dtype=bool)
    trunc = np.asarray(ep.truncations, dtype=bool)
    if (term[:-1] | trunc[:-1]).any():
        raise ValueError(f"offline episode {index}: only the last step may be terminated or truncated")
    return {
        "obs": obs.reshape(t_len, -1),  # (T, *obs_shape) -> (T, obs_dim)
        "next_obs": next_obs.reshape(t_len, -1),
        "actions": actions.reshape(t_len, -1),  # (T, *action_shape) -> (T, action_dim)
        "rewards": np.asarray(ep.rewards, dtype=np.float32),
        "terminated": term,
    }


def offline_windows(t_len: int, terminated: bool, chunk_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    The windows of Eq. 4 that start at every step of a logged episode of ``T`` steps:
    ``L = min(k, steps to the episode end)``, bootstrap unless the window ends at a termination.

    :param t_len: ``T``
    :param terminated: the episode terminated at its last step (else it was truncated)
    :param chunk_size: ``k``
    :return: the step index ``t``, the horizon ``L`` and the bootstrap mask, each of shape ``(T,)``
    """
    steps = np.arange(t_len)
    horizon = np.minimum(chunk_size, t_len - steps)
    # the window ends at the last step of the episode iff steps + horizon == t_len
    return steps, horizon, ~((steps + horizon == t_len) & terminated)


class _Steps:
    """Per-step storage with shape ``(capacity, n_envs, ...)``."""

    def __init__(
        self, capacity: int, n_envs: int, obs_dim: int, action_dim: int, chunk_size: int, plans: bool
    ):
        self.capacity, self.n_envs, self.chunk_size = capacity, n_envs, chunk_size
        self.obs = np.zeros((capacity, n_envs, obs_dim), dtype=np.float32)
        self.next_obs = np.zeros((capacity, n_envs, obs_dim), dtype=np.float32)
        self.actions = np.zeros((capacity, n_envs, action_dim), dtype=np.float32)
        self.rewards = np.zeros((capacity, n_envs), dtype=np.float32)
        self.terminated = np.zeros((capacity, n_envs), dtype=bool)
        #: index of the step inside its episode (0 at the first step)
        self.episode_step = np.zeros((capacity, n_envs), dtype=np.int32)
        #: window length ``L`` of a sample starting here; 0 = no complete window starts here
        self.horizon = np.zeros((capacity, n_envs), dtype=np.int32)
        self.bootstrap = np.zeros((capacity, n_envs), dtype=bool)
        #: the plan selected at a plan start; when the plan closes, its first ``L`` entries become the
        #: executed actions: the sample's chunk (Eq. 8)
        self.plans = np.zeros((capacity, n_envs, chunk_size, action_dim), dtype=np.float32) if plans else None

    def grow(self, capacity: int) -> None:
        for name in (
            "obs",
            "next_obs",
            "actions",
            "rewards",
            "terminated",
            "episode_step",
            "horizon",
            "bootstrap",
        ):
            old = getattr(self, name)
            new = np.zeros((capacity,) + old.shape[1:], dtype=old.dtype)
            new[: old.shape[0]] = old
            setattr(self, name, new)
        self.capacity = capacity

    def gather(
        self,
        rows: np.ndarray,
        history_len: int,
        out: ChunkReplaySamples,
        obs_groups: np.ndarray,
        action_groups: np.ndarray,
        lo: int,
    ) -> None:
        """
        Write the samples starting at the flat rows ``rows = slot * n_envs + env`` into
        ``out[lo : lo + len(rows)]`` (see :class:`ChunkReplaySamples`), with histories of
        ``history_len`` steps. Before the episode start the histories repeat its first observation and
        hold zero actions.

        Step ``t + j`` of a sample's env is the flat row ``rows + j * n_envs``, taken modulo the ring
        (``mode="wrap"``); rows outside the sample's episode are only read where they are masked.
        """
        s, k, ell, n = self, self.chunk_size, history_len, self.n_envs
        obs_dim, a_dim = self.obs.shape[-1], self.actions.shape[-1]
        sl = slice(lo, lo + rows.size)
        horizon = s.horizon.reshape(-1).take(rows).astype(np.intp)  # (m,) L
        out.horizons[sl] = horizon
        out.bootstrap[sl] = s.bootstrap.reshape(-1).take(rows)
        steps = np.stack([np.zeros_like(horizon), horizon])  # (2, m) offsets of t and t + L
        count = s.episode_step.reshape(-1).take(rows)  # (m,) steps before t in its episode
        base, first = rows[:, None], -count[:, None]  # (m, 1): row of t, offset of the episode start
        # offsets from t of the action histories a_{t+j-ℓ:t+j-1}, (2, m, ℓ)
        offsets = steps[..., None] + np.arange(-ell, 0)
        actions = s.actions.reshape(-1, a_dim)
        actions.take(base + offsets * n, axis=0, out=action_groups[:, sl], mode="wrap")
        action_groups[:, sl] *= (offsets >= first)[..., None]  # zero actions before the episode start
        # o_{t+j-ℓ+1:t+j}; before the episode start its first observation
        obs_rows = base + np.maximum(offsets + 1, first) * n
        s.obs.reshape(-1, obs_dim).take(obs_rows, axis=0, out=obs_groups[:, sl], mode="wrap")
        last = rows + (steps[1:] - 1) * n  # (1, m) step t+L-1: o_{t+L} is its next observation
        next_obs = s.next_obs.reshape(-1, obs_dim)
        next_obs.take(last, axis=0, out=obs_groups[1:, sl, -1], mode="wrap")
        ahead = np.arange(k)
        inside = ahead < horizon[:, None]  # (m, k)
        chunk_rows = rows[:, None] + ahead * n  # (m, k)
        s.rewards.reshape(-1).take(chunk_rows, out=out.rewards[sl], mode="wrap")
        out.rewards[sl] *= inside
        if s.plans is not None:  # the executed actions, then the plan's unexecuted tail (see ChunkReplayBuffer._write_chunks)
            s.plans.reshape(-1, k, a_dim).take(rows, axis=0, out=out.chunks[sl])
            out.chunk_mask[sl] = 1.0  # no padding: the tail is the plan's own
        else:  # the next k executed actions, zeros after the episode end
            actions.take(chunk_rows, axis=0, out=out.chunks[sl], mode="wrap")
            np.copyto(out.chunks[sl], 0.0, where=~inside[..., None])
            out.chunk_mask[sl] = inside


class _StartIndex:
    """
    The valid sample starts of the online ring, a set of flat indices ``slot * n_envs + env`` with
    O(1) insertion and removal (a removed member's place is taken by the last member) and uniform
    sampling in O(batch), whatever the ring's size.
    """

    def __init__(self, capacity: int):
        dtype = np.int32 if capacity < 2**31 else np.int64
        #: the members are ``items[:size]``; in increasing order as long as they were inserted so
        self.items = np.zeros(capacity, dtype=dtype)
        #: place of a member in ``items``, -1 for a non-member, shape ``(capacity,)``
        self.place = np.full(capacity, -1, dtype=dtype)
        self.size = 0

    def insert(self, flat: np.ndarray) -> None:
        """Add the distinct indices ``flat`` (members already in are left alone), in increasing order."""
        flat = np.sort(flat[self.place[flat] < 0])
        end = self.size + flat.size
        self.items[self.size : end] = flat
        self.place[flat] = np.arange(self.size, end)
        self.size = end

    def remove(self, flat: np.ndarray) -> None:
        """Remove the distinct indices ``flat`` (non-members are ignored)."""
        flat = flat[self.place[flat] >= 0]
        if flat.size == 0:
            return
        holes = self.place[flat]
        self.place[flat] = -1
        end = self.size - flat.size
        tail = self.items[end : self.size]
        kept = tail[self.place[tail] >= 0]  # members beyond the new end move into the holes before it
        holes = holes[holes < end]
        self.items[holes] = kept
        self.place[kept] = holes
        self.size = end

    def clear(self) -> None:
        self.place[self.items[: self.size]] = -1
        self.size = 0

    def sample(self, n: int) -> np.ndarray:
        """``n`` members drawn uniformly with replacement (NumPy's global RNG, seeded by SB3)."""
        return self.items[np.random.randint(0, self.size, size=n)]  # noqa: NPY002

    def members(self) -> np.ndarray:
        """The members in increasing order (int64)."""
        return np.sort(self.items[: self.size]).astype(np.int64)


class ChunkReplayBuffer(BaseBuffer):
    """
    Replay buffer for chunked off-policy learning (online ring + offline episodes).

    It stays over 300 lines for the bookkeeping of the online ring that keeps sampling O(batch): open
    plans (Eq. 8), closing windows (``online_targets="window"``) and the index of valid starts as the
    ring overwrites itself.

    :param buffer_size: capacity of the online ring (steps per env)
    :param observation_space: Box observation space
    :param action_space: Box action space
    :param device: torch device of the sampled tensors
    :param n_envs: number of parallel environments
    :param chunk_size: ``k`` (this and the next arguments are keyword-only and required:
        :class:`~sb3_ua2c.ua2c.UA2C` passes its own, where their defaults are declared)
    :param history_len: ``ℓ``
    :param offline_ratio: fraction of each batch drawn from the offline part when both parts hold data
    :param online_targets: ``"prefix"`` (the paper, Eq. 8): one online sample per plan, its chunk the
        selected plan and its horizon the executed length ``L_t``; ``"window"``: every online step
        starts a sample whose chunk is the next ``k`` executed actions (``min(k, steps to the episode
        end)``), i.e. the target of Eq. 4 as for the offline windows; ``"auto"``: ``"prefix"`` if,
        when the first online step is stored, the buffer holds offline episodes and
        ``offline_ratio > 0``, else ``"window"`` (:attr:`active_online_targets`)
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        *,
        chunk_size: int,
        history_len: int,
        offline_ratio: float,
        online_targets: str,
    ) -> None:
        super().__init__(buffer_size, observation_space, action_space, device, n_envs=n_envs)
        self.chunk_size = chunk_size
        self.history_len = history_len
        self.offline_ratio = offline_ratio
        self.online_targets = online_targets
        check_arguments(
            buffer_size=buffer_size,
            chunk_size=chunk_size,
            history_len=history_len,
            offline_ratio=offline_ratio,
            online_targets=online_targets,
        )
        if buffer_size < chunk_size + history_len:
            raise ValueError(f"buffer_size={buffer_size} must be >= chunk_size + history_len")
        self.obs_dim = int(np.prod(self.obs_shape))
        #: ``"prefix"`` or ``"window"``; ``None`` while ``online_targets="auto"`` waits for the first step
        self._active_targets: str | None = None if online_targets == "auto" else online_targets
        self.online = self._online_steps(self._active_targets == "prefix")
        self.offline = _Steps(0, 1, self.obs_dim, self.action_dim, chunk_size, plans=False)
        self.offline_size = 0
        self._next_episode_step = np.zeros(n_envs, dtype=np.int64)
        #: per env: start position of the open plan (-1 = none), its ``L_t`` and the steps executed
        self._plan_start = np.full(n_envs, -1, dtype=np.int64)
        self._plan_target = np.zeros(n_envs, dtype=np.int64)
        self._plan_count = np.zeros(n_envs, dtype=np.int64)
        #: the valid online sample starts, kept up to date by :meth:`add`
        self._starts = _StartIndex(buffer_size * n_envs)

    def _online_steps(self, plans: bool) -> _Steps:
        return _Steps(self.buffer_size, self.n_envs, self.obs_dim, self.action_dim, self.chunk_size, plans=plans)

    @property
    def active_online_targets(self) -> str | None:
        """
        The online samples in use, ``"prefix"`` (Eq. 8) or ``"window"``; with ``online_targets="auto"``
        ``None`` until the first online step is stored (and again after :meth:`reset`).
        """
        return self._active_targets

    def _resolve_online_targets(self) -> None:
        """``online_targets="auto"``, at the first online step: Eq. 8 offline-to-online, else windows."""
        mixed = self.offline_size > 0 and self.offline_ratio > 0.0
        self._active_targets = "prefix" if mixed else "window"
        if mixed:  # the online part is empty: give it the plan storage
            self.online = self._online_steps(plans=True)

    # ------------------------------------------------------------------ online part
    def add(  # type: ignore[override]
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        episode_start: np.ndarray,
        new_plan: np.ndarray,
        plans: np.ndarray,
        plan_lengths: np.ndarray,
    ) -> None:
        """
        Store one step of every environment.

        :param obs: ``o_t``, shape ``(n_envs, *obs_shape)``
        :param next_obs: ``o_{t+1}`` (the terminal observation at an episode end), same shape
        :param action: executed normalised action, shape ``(n_envs, action_dim)``
        :param reward: shape ``(n_envs,)``
        :param terminated: episode terminated after this step, shape ``(n_envs,)``
        :param truncated: episode truncated (time limit) after this step, shape ``(n_envs,)``
        :param episode_start: ``o_t`` is the first observation of an episode, shape ``(n_envs,)``
        :param new_plan: a plan starts at this step, shape ``(n_envs,)``
        :param plans: current plans, shape ``(n_envs, k, action_dim)``
        :param plan_lengths: ``L_t`` of the current plans, shape ``(n_envs,)``
        """
        if self._active_targets is None:
            self._resolve_online_targets()
        s, p, n = self.online, self.pos, self.n_envs
        episode_start = np.asarray(episode_start, dtype=bool).reshape(n)
        new_plan = np.asarray(new_plan, dtype=bool).reshape(n)
        terminated = np.asarray(terminated, dtype=bool).reshape(n)
        done = terminated | np.asarray(truncated, dtype=bool).reshape(n)
        if self.full:
            self._retire(p)
        starting = s.plans is not None and new_plan.any()
        if starting:
            plan_lengths = np.asarray(plan_lengths).reshape(n)[new_plan]
            if plan_lengths.min() < 1 or plan_lengths.max() > self.chunk_size:
                raise ValueError(
                    f"plan_lengths of new plans must be in [1, chunk_size={self.chunk_size}], "
                    f"got {plan_lengths.tolist()}"
                )
        if s.plans is not None:
            # a plan left open (e.g. learn() restarted the episodes) closes with a bootstrap
            self._close_plans((new_plan | episode_start) & (self._plan_start >= 0), np.zeros_like(new_plan))
        s.obs[p] = np.reshape(obs, (n, -1))  # cast to float32 on assignment
        s.next_obs[p] = np.reshape(next_obs, (n, -1))
        s.actions[p] = np.reshape(action, (n, -1))
        s.rewards[p] = np.reshape(reward, n)
        s.terminated[p] = terminated
        self._next_episode_step[episode_start] = 0
        s.episode_step[p] = self._next_episode_step
        self._next_episode_step += 1
        s.horizon[p] = 0
        s.bootstrap[p] = False
        if s.plans is None:
            self._close_windows(p, done, terminated)
        else:
            if starting:
                s.plans[p, new_plan] = np.asarray(plans)[new_plan]
                self._plan_start[new_plan] = p
                self._plan_target[new_plan] = plan_lengths
                self._plan_count[new_plan] = 0
            has_plan = self._plan_start >= 0
            self._plan_count[has_plan] += 1
            self._close_plans(has_plan & (done | (self._plan_count >= self._plan_target)), terminated)
        self.pos += 1
        if self.pos == self.buffer_size:
            self.full = True
            self.pos = 0

    def _retire(self, p: int) -> None:
        """
        Before slot ``p`` of the full ring is overwritten: drop its starts, and those whose history
        ``a_{t-ℓ:t-1}`` reaches back to it (the starts at ``p + d``, ``d = 1..ℓ``, with ``min(episode
        step, ℓ) >= d``: their oldest slot of history becomes ``p``).
        """
        ell, n, steps = self.history_len, self.n_envs, self.online.episode_step
        if p + ell < self.buffer_size:
            steps = steps[p : p + ell + 1]  # (ℓ+1, n_envs)
        else:
            steps = steps.take(np.arange(p, p + ell + 1), axis=0, mode="wrap")
        gone = np.flatnonzero(steps >= np.arange(ell + 1)[:, None])  # d * n_envs + env
        self._starts.remove((gone + p * n) % (self.buffer_size * n))

    def _admit(self, starts: np.ndarray, envs: np.ndarray) -> None:
        """Add the starts whose window just closed to the index, unless their history left the ring."""
        self._starts.insert((starts * self.n_envs + envs)[self._history_in_ring(starts, envs)])

    def _history_in_ring(self, starts: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """
        Whether the slots ``starts - min(episode step, ℓ) .. starts`` of ``envs`` all hold data written
        since the last :meth:`reset` and not overwritten since, during :meth:`add` at ``self.pos``.
        """
        if self.full:  # the oldest slot still in the ring is pos + 1 (slot pos is being written)
            age = (starts - self.pos - 1) % self.buffer_size
        else:
            age = np.where(starts <= self.pos, starts, -1)
        return np.minimum(self.online.episode_step[starts, envs], self.history_len) <= age

    def _close_plans(self, mask: np.ndarray, terminated: np.ndarray) -> None:
        if not mask.any():
            return
        s, envs = self.online, np.flatnonzero(mask)
        starts, executed = self._plan_start[envs], self._plan_count[envs]
        s.horizon[starts, envs] = executed
        s.bootstrap[starts, envs] = ~terminated[envs]
        self._write_chunks(starts, envs, executed)
        self._plan_start[envs] = -1
        self._admit(starts, envs)

    def _write_chunks(self, starts: np.ndarray, envs: np.ndarray, executed: np.ndarray) -> None:
        """Chunks (Eq. 8) at closed plan starts: the ``executed`` actions, then the unexecuted tails."""
        s, u = self.online, np.arange(self.chunk_size)
        actions = s.actions[(starts[:, None] + u) % self.buffer_size, envs[:, None]]  # (c, k, action_dim)
        done = (u < executed[:, None])[..., None]  # (c, k, 1)
        s.plans[starts, envs] = np.where(done, actions, s.plans[starts, envs])

    def _close_windows(self, p: int, done: np.ndarray, terminated: np.ndarray) -> None:
        """
        ``online_targets="window"``: step ``p`` completes the window starting ``k - 1`` steps earlier in
        its episode; at an episode end the shorter windows of its last ``k - 1`` starts close as well
        (horizon = steps to the end, bootstrap unless terminated), as :meth:`_add_offline_episode` does.
        """
        s, k = self.online, self.chunk_size
        steps = s.episode_step[p]  # (n_envs,) index of step p inside its episode
        closed_starts, closed_envs = [], []
        # the window a_{p-length+1..p}, inside the episode; shorter ones only at an episode end
        for length in range(1, k + 1) if done.any() else (k,):
            closes = done if length < k else np.ones_like(done)
            envs = np.flatnonzero((steps >= length - 1) & closes)
            start = (p - length + 1) % self.buffer_size
            s.horizon[start, envs] = length
            s.bootstrap[start, envs] = ~terminated[envs]
            closed_starts.append(np.full(envs.size, start))
            closed_envs.append(envs)
        self._admit(np.concatenate(closed_starts), np.concatenate(closed_envs))

    def reset(self) -> None:
        super().reset()
        self._plan_start[:] = -1
        self.online.horizon[:] = 0
        self._starts.clear()
        if self.online_targets == "auto":  # the online part is empty again: choose again
            self._active_targets = None
            if self.online.plans is not None:
                self.online = self._online_steps(plans=False)

    # ------------------------------------------------------------------ offline part
    def add_offline_episodes(self, episodes: Iterable[Any]) -> int:
        """
        Append whole logged episodes; every step becomes a sample start with the logged actions as the
        chunk (Eq. 4): ``L = min(k, steps to the episode end)``, bootstrap unless the episode
        terminated inside the window.

        :param episodes: :class:`~sb3_ua2c.offline.Episode` objects or mappings with their field names
            (:meth:`~sb3_ua2c.offline.Episode.coerce`), actions normalised
        :return: number of steps added
        """
        added = 0
        for i, ep in enumerate(episodes):
            added += self._add_offline_episode(Episode.coerce(ep), i)
        return added

    def _add_offline_episode(self, ep: Episode, index: int) -> int:
        arrays = episode_arrays(ep, index, self.obs_dim, self.action_dim)
        t_len = arrays["actions"].shape[0]
        s, start = self.offline, self.offline_size
        if start + t_len > s.capacity:
            s.grow(max(2 * s.capacity, start + t_len, 1024))
        sl = slice(start, start + t_len)
        for name, array in arrays.items():
            getattr(s, name)[sl, 0] = array
        s.episode_step[sl, 0], s.horizon[sl, 0], s.bootstrap[sl, 0] = offline_windows(
            t_len, bool(arrays["terminated"][-1]), self.chunk_size
        )
        self.offline_size += t_len
        return t_len

    # ------------------------------------------------------------------ sampling
    def online_starts(self) -> np.ndarray:
        """The valid online sample starts, flat indices ``slot * n_envs + env`` in increasing order (int64)."""
        return self._starts.members()

    def reindex(self) -> None:
        """
        Recompute the valid online starts by scanning the whole ring, O(buffer_size): a complete window
        starts there and its history ``o_{t-ℓ+1:t}``, ``a_{t-ℓ:t-1}`` (``min(episode step, ℓ)`` slots back)
        is still in the ring. :meth:`add` keeps the index up to date itself; this is for storage written
        directly (a benchmark filling the ring) and the reference the index is tested against.
        """
        size = self.buffer_size if self.full else self.pos
        slots = np.arange(size)
        age = (slots - self.pos) % self.buffer_size if self.full else slots  # (size,) 0 = oldest
        lookback = np.minimum(self.online.episode_step[:size], self.history_len)  # (size, n_envs)
        self._starts.clear()
        self._starts.insert(np.flatnonzero((self.online.horizon[:size] > 0) & (lookback <= age[:, None])))

    def n_samples(self) -> tuple[int, int]:
        """Number of sample starts available ``(online, offline)``."""
        return self._starts.size, int(self.offline_size)

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ChunkReplaySamples:  # type: ignore[override]
        """
        Sample ``batch_size`` chunk transitions; a fraction ``offline_ratio`` comes from the offline part
        when both parts hold data. The cost does not depend on the buffer's size.

        :param batch_size: number of samples
        :param env: optional ``VecNormalize`` to normalise observations and rewards
        :return: a batch of chunk transitions
        """
        n_on_avail, n_off_avail = self.n_samples()
        if n_on_avail == 0 and n_off_avail == 0:
            raise ValueError("the replay buffer holds no complete chunk transition yet")
        if n_on_avail == 0:
            n_off = batch_size
        elif n_off_avail == 0:
            n_off = 0
        else:
            n_off = int(round(self.offline_ratio * batch_size))
        k, ell, a_dim = self.chunk_size, self.history_len, self.action_dim
        # the histories at t and at t + L side by side, (2, B, ℓ, dim): one read fills both
        obs_groups = np.empty((2, batch_size, ell, self.obs_dim), dtype=np.float32)
        action_groups = np.empty((2, batch_size, ell, a_dim), dtype=np.float32)
        out = ChunkReplaySamples(
            obs_groups[0],
            action_groups[0],
            np.empty((batch_size, k, a_dim), dtype=np.float32),
            np.empty((batch_size, k), dtype=np.float32),
            np.empty(batch_size, dtype=np.float32),
            np.empty(batch_size, dtype=np.float32),
            obs_groups[1],
            action_groups[1],
            np.empty((batch_size, k), dtype=np.float32),
        )
        if n_off > 0:
            rows = np.random.randint(0, n_off_avail, size=n_off)  # noqa: NPY002 - global RNG seeded by SB3
            self.offline.gather(rows, ell, out, obs_groups, action_groups, 0)
        if batch_size - n_off > 0:
            rows = self._starts.sample(batch_size - n_off).astype(np.intp)
            self.online.gather(rows, ell, out, obs_groups, action_groups, n_off)
        if env is not None:
            inside = np.arange(k)[None, :] < out.horizons[:, None]  # (B, k)
            normalized = {
                name: self._normalize_obs(getattr(out, name), env).astype(np.float32)
                for name in ("observation_history", "next_observation_history")
            }
            out = out._replace(
                **normalized, rewards=self._normalize_reward(out.rewards, env).astype(np.float32) * inside
            )
        return ChunkReplaySamples(*(self.to_torch(a) for a in out))

    def to_torch(self, array: np.ndarray, copy: bool = False) -> th.Tensor:
        """The sampled arrays are fresh: share their memory unless asked to copy."""
        return th.tensor(array, device=self.device) if copy else th.from_numpy(array).to(self.device)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ChunkReplaySamples:
        raise NotImplementedError("use ChunkReplayBuffer.sample()")
