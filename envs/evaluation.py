"""Evaluation on ``MixedTraffic-v0``: reward, smoothness (cumulative jerk), collisions, merges and
the executed chunk lengths L_t of a checkpoint, on seeded scenarios."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from envs.collection import BehaviourConfig, BehaviourDriver, make_traffic_env
from sb3_ua2c import UA2C, ExecutionRule
from sb3_ua2c.checks import check_int
from sb3_ua2c.execution import length_shares
from sb3_ua2c.offline import check_spaces_match
from sb3_ua2c.pipeline import load_checkpoint


@dataclass(frozen=True)
class EpisodeMetrics:
    """What :func:`evaluate` measures per episode (``MixedTraffic-v0`` info keys)."""

    seed: int
    reward: float
    length: int
    cumulative_jerk: float  # Σ_t |jerk_t| [m/s³], the smoothness cost of Fig. 2(b)
    collision: bool
    merge_success: bool
    mean_speed: float  # [m/s]
    mean_executed_length: float  # mean L_t of the plans made in the episode (Eq. 7)
    plan_lengths: tuple[int, ...] = ()  # L_t of every plan of the episode, in order (1 per decision of a peer)
    acting_seconds: float = 0.0  # wall seconds in ``predict`` over the episode (replanning and the executor)

    @property
    def ms_per_plan(self) -> float:
        """Wall milliseconds of ``predict`` per plan made: the cost of a replanning, as the policy acts."""
        return 1000.0 * self.acting_seconds / len(self.plan_lengths) if self.plan_lengths else math.nan

    @property
    def jerk_per_step(self) -> float:
        """``cumulative_jerk / length`` [m/s³]: smoothness that does not reward ending an episode early."""
        return self.cumulative_jerk / self.length if self.length else math.nan


def evaluate(
    checkpoint: str | os.PathLike | UA2C | Any,
    n_episodes: int = 5,
    seeds: tuple[int, ...] = (0,),
    env_settings_: dict[str, Any] | None = None,
    entropy_threshold: float | None = None,
    deterministic: bool = True,
    n_elite: int | None = None,
    flow_steps: int | None = None,
    selection: str | None = None,
    execution: ExecutionRule | None = None,
) -> list[EpisodeMetrics]:
    """Run a checkpoint for ``n_episodes`` episodes per seed with the stateful ``predict``.

    Episode ``i`` of seed ``s`` is reset with seed ``1000 * s + i`` (the same scenarios for every
    checkpoint evaluated with the same seeds). With ``deterministic=False`` every replanning draws
    fresh candidate noise, as the rollouts of Phase 2 do; the noise of an episode comes from torch's
    generator seeded with the episode's seed (the global generator is restored afterwards), so
    sampled evaluations are reproducible too.

    :param checkpoint: a UA2C ``.zip`` path, a UA2C model, or any policy with SB3's
        ``predict(obs, state=None, episode_start=None, deterministic=True)`` and
        ``observation_space``/``action_space`` (e.g. SB3's SAC, or :mod:`experiments.peers`' adapter of a
        d3rlpy policy): such a policy acts one action per decision (``mean_executed_length`` 1) and
        takes none of the UA2C overrides below
    :param n_episodes: episodes per seed
    :param seeds: evaluation seeds
    :param env_settings_: :func:`~envs.collection.make_traffic_env` arguments (default ``MixedTraffic-v0``)
    :param entropy_threshold: override δ for execution
    :param deterministic: fixed candidate noise (see ``UA2CPolicy.predict``); ``False``: fresh,
        seeded noise per replanning
    :param n_elite: override how many best candidates a replanning averages (``UA2C.set_n_elite``)
    :param flow_steps: override the Euler steps of the sampler when acting (``UA2C.set_flow_steps``)
    :param selection: override how a replanning selects its chunk (``UA2C.set_selection``)
    :param execution: override the execution rule (``UA2C.set_execution_rule``; not with ``entropy_threshold``)
    """
    check_int("n_episodes", n_episodes)
    settings = dict(env_settings_ or {"env_id": "MixedTraffic-v0"})
    env = make_traffic_env(**settings)
    try:
        if isinstance(checkpoint, str | os.PathLike):
            model = load_checkpoint(checkpoint, env)
        elif isinstance(checkpoint, UA2C) or callable(getattr(checkpoint, "predict", None)):
            model = checkpoint
            check_spaces_match(model.observation_space, model.action_space, env, what="the model")
        else:
            raise TypeError(f"checkpoint must be a path or a policy with predict(), got {type(checkpoint).__name__}")
        if entropy_threshold is not None and execution is not None:
            raise ValueError("give entropy_threshold or execution, not both")
        overrides = {"entropy_threshold": entropy_threshold, "n_elite": n_elite, "flow_steps": flow_steps,
                     "selection": selection, "execution": execution}
        given = sorted(name for name, value in overrides.items() if value is not None)
        if given and not isinstance(model, UA2C):
            raise ValueError(f"{given} apply to UA2C only, not to a {type(model).__name__}")
        if entropy_threshold is not None:
            model.set_execution_rule(ExecutionRule(entropy_threshold=entropy_threshold))
        if n_elite is not None:
            model.set_n_elite(n_elite)
        if flow_steps is not None:
            model.set_flow_steps(flow_steps)
        if selection is not None:
            model.set_selection(selection)
        if execution is not None:
            model.set_execution_rule(execution)
        results = []
        for s in seeds:
            for i in range(n_episodes):
                results.append(_run_episode(model, env, 1000 * int(s) + i, deterministic))
        return results
    finally:
        env.close()


def _run_episode(model: Any, env: Any, seed: int, deterministic: bool) -> EpisodeMetrics:
    if deterministic:
        return _drive_episode(model, env, seed, deterministic)
    with th.random.fork_rng(devices=[]):  # seeded candidate noise, the caller's generator untouched
        th.manual_seed(seed)
        return _drive_episode(model, env, seed, deterministic)


class _EpisodeMeter:
    """The metrics of :class:`EpisodeMetrics`, accumulated step by step from ``MixedTraffic-v0``'s info."""

    def __init__(self) -> None:
        self.total, self.jerk, self.speeds, self.steps = 0.0, 0.0, [], 0
        self.collision = self.merged = False

    def add(self, reward: float, info: dict[str, Any]) -> None:
        self.total += float(reward)
        self.jerk += abs(float(info.get("jerk", 0.0)))
        self.speeds.append(float(info.get("av_speed", math.nan)))
        self.collision |= bool(info.get("collision", False))
        self.merged |= bool(info.get("merge_done", False))
        self.steps += 1

    def metrics(self, seed: int, lengths: list[int], acting_seconds: float = 0.0) -> EpisodeMetrics:
        return EpisodeMetrics(
            seed=seed, reward=self.total, length=self.steps, cumulative_jerk=self.jerk, collision=self.collision,
            merge_success=self.merged, mean_speed=float(np.nanmean(self.speeds)),
            mean_executed_length=float(np.mean(lengths)), plan_lengths=tuple(lengths), acting_seconds=acting_seconds,
        )


def _drive_episode(model: Any, env: Any, seed: int, deterministic: bool) -> EpisodeMetrics:
    obs, info = env.reset(seed=seed)
    state, start = None, np.ones(1, dtype=bool)
    meter, lengths = _EpisodeMeter(), []
    done, acting = False, 0.0
    while not done:
        clock = time.perf_counter()
        action, state = model.predict(obs, state=state, episode_start=start, deterministic=deterministic)
        acting += time.perf_counter() - clock
        if not hasattr(state, "plan_position"):  # a one-action-per-decision policy
            lengths.append(1)
        elif int(state.plan_position[0]) == 1:  # a plan was made at this step
            lengths.append(int(state.plan_length[0]))
        start = np.zeros(1, dtype=bool)
        obs, reward, terminated, truncated, info = env.step(action)
        meter.add(reward, info)
        done = terminated or truncated
    return meter.metrics(seed, lengths, acting)


def evaluate_behaviour(
    behaviour: BehaviourConfig | None = None,
    n_episodes: int = 5,
    seeds: tuple[int, ...] = (0,),
    env_settings_: dict[str, Any] | None = None,
) -> list[EpisodeMetrics]:
    """The behaviour policy that collects the datasets (:class:`~envs.collection.BehaviourDriver`) on the
    scenarios :func:`evaluate` uses: episode ``i`` of seed ``s`` is reset with seed ``1000 * s + i``,
    and the behaviour's own randomness is seeded with it too. One action per decision (L_t = 1).

    :param behaviour: the behaviour policy (default :class:`~envs.collection.BehaviourConfig`; a
        dataset's is in its metadata, ``behaviour_config``)
    :param n_episodes: episodes per seed
    :param seeds: evaluation seeds
    :param env_settings_: :func:`~envs.collection.make_traffic_env` arguments (default ``MixedTraffic-v0``)
    """
    check_int("n_episodes", n_episodes)
    behaviour = behaviour or BehaviourConfig()
    env = make_traffic_env(**dict(env_settings_ or {"env_id": "MixedTraffic-v0"}))
    try:
        results = []
        for s in seeds:
            for i in range(n_episodes):
                seed = 1000 * int(s) + i
                driver = BehaviourDriver(env, behaviour, np.random.default_rng(seed))
                driver.reset(seed)
                meter, done = _EpisodeMeter(), False
                while not done:
                    _, reward, terminated, truncated, info, _ = driver.step()
                    meter.add(reward, info)
                    done = terminated or truncated
                results.append(meter.metrics(seed, [1] * meter.steps))
        return results
    finally:
        env.close()


SUMMARY_KEYS = (
    "reward", "cumulative_jerk", "jerk_per_step", "collision", "merge_success", "mean_speed", "mean_executed_length",
)


def summarize(results: list[EpisodeMetrics]) -> dict[str, float]:
    """Means over episodes (collision and merge as rates) plus the episode count."""
    if not results:
        raise ValueError("no episodes to summarize")
    out = {key: float(np.mean([float(getattr(r, key)) for r in results])) for key in SUMMARY_KEYS}
    out["episodes"] = len(results)
    return out


def plan_length_shares(results: list[EpisodeMetrics], chunk_size: int) -> list[float]:
    """The ``L_t`` histogram of the plans of ``results``: the share of plans with ``L_t = 1 .. k``
    (``(k,)`` fractions summing to 1; zeros when no plan was made)."""
    return length_shares([n for r in results for n in r.plan_lengths], chunk_size)


#: the keys of :data:`SUMMARY_KEYS` that are rates of a yes/no outcome per episode
RATE_KEYS = ("collision", "merge_success")
#: the columns of :func:`format_table`: ``(header, summary key)``
TABLE_COLUMNS = (("reward", "reward"), ("cum. jerk", "cumulative_jerk"), ("collision", "collision"),
                 ("merge", "merge_success"), ("speed", "mean_speed"), ("mean L_t", "mean_executed_length"))


def episode_intervals(results: list[EpisodeMetrics], confidence: float = 0.95) -> dict[str, tuple[float, float]]:
    """
    Confidence intervals of :func:`summarize`'s means over the episodes of one run: Student's t interval
    of the mean (scipy) for the continuous metrics, Wilson's score interval (scipy's ``binomtest``) for the
    rates :data:`RATE_KEYS`. An interval over the scenarios of one run, not over training runs.

    :param results: the episodes (at least 1; with 1, or no spread, the interval is the mean itself)
    :param confidence: the interval's level
    :return: ``{key: (low, high)}`` for every key of :data:`SUMMARY_KEYS`
    """
    from scipy import stats

    if not results:
        raise ValueError("no episodes to summarize")
    n, out = len(results), {}
    for key in SUMMARY_KEYS:
        x = np.array([float(getattr(r, key)) for r in results])
        if key in RATE_KEYS:
            ci = stats.binomtest(int(x.sum()), n).proportion_ci(confidence, method="wilson")
            out[key] = (float(ci.low), float(ci.high))
        elif n < 2 or not np.ptp(x) > 0:
            out[key] = (float(x.mean()), float(x.mean()))
        else:
            low, high = stats.t.interval(confidence, n - 1, loc=x.mean(), scale=stats.sem(x))
            out[key] = (float(low), float(high))
    return out


def _interval_cell(low: float, high: float) -> str:
    digits = 2 if max(abs(low), abs(high)) < 10 else 1 if max(abs(low), abs(high)) < 100 else 0
    return f"{low:.{digits}f}..{high:.{digits}f}"


def format_table(
    rows: dict[str, dict[str, float]], intervals: dict[str, dict[str, tuple[float, float]]] | None = None
) -> str:
    """
    A plain-text table, one row per method, 95 characters wide (fits a terminal and the README).

    :param rows: ``{method: summary}`` (:func:`summarize`)
    :param intervals: ``{method: intervals}`` (:func:`episode_intervals`): each such method's row is followed
        by a row ``95 % CI`` of ``low..high`` cells
    """
    lines = [" | ".join(f"{h:>11}" for h in ("method", *(header for header, _ in TABLE_COLUMNS)))]
    lines.append("-|-".join("-" * 11 for _ in range(len(TABLE_COLUMNS) + 1)))
    for name, s in rows.items():
        lines.append(" | ".join([f"{name:>11}"] + [f"{s[key]:11.3f}" for _, key in TABLE_COLUMNS]))
        if intervals and name in intervals:
            cells = [_interval_cell(*intervals[name][key]) for _, key in TABLE_COLUMNS]
            lines.append(" | ".join([f"{'95 % CI':>11}"] + [f"{c:>11}" for c in cells]))
    return "\n".join(lines)


__all__ = [
    "RATE_KEYS", "SUMMARY_KEYS", "EpisodeMetrics", "episode_intervals", "evaluate", "evaluate_behaviour", "format_table",
    "plan_length_shares", "summarize",
]
