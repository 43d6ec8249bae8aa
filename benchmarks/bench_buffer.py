"""Cost of :class:`~sb3_ua2c.buffers.ChunkReplayBuffer` next to SB3's ``ReplayBuffer``, measured in one run.

Usage::

    python benchmarks/bench_buffer.py [--sizes 10000 100000 1000000] [--fill bulk|add]

At each buffer size, with one env, batch 256, ``ℓ = 4``, ``k = 5``, observation dim 38 (MixedTraffic's
20 plus the driving-style context) and action dim 2, it prints:

* ``sample()`` time of a full ring of each part of the chunk buffer, next to SB3's
  ``ReplayBuffer.sample`` of the same size and dims, and the ratio ours / SB3: the online ring with
  ``online_targets="prefix"`` (the default) and ``"window"``, the offline part alone (as many steps),
  and both parts mixed half and half (``offline_ratio=0.5``);
* ``add()`` time per step into the full ring (overwriting, with the bookkeeping of the valid starts),
  next to SB3's ``ReplayBuffer.add``;
* the memory of the arrays of the online ring (prefix) and of SB3's buffer.

The data are episodes of 200 steps (truncated), plans of ``L_t`` uniform in ``1..k``. ``--fill bulk``
(default) writes a full ring's arrays in one vectorised pass, exactly as ``add()`` would have left
them, and builds the index of valid starts with the one scan that also serves buffers pickled
before the index existed; ``--fill add`` calls ``add()`` for every step instead (slower).

Times are medians of the CPU time of the calling thread over interleaved blocks of calls (one torch
thread), so other processes sharing the cores do not count; read the ratios, not the absolute times.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_ua2c.buffers import ChunkReplayBuffer

OBS_DIM, ACTION_DIM, HISTORY, CHUNK, BATCH, EPISODE = 38, 2, 4, 5, 256, 200
OBS_SPACE = spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
ACTION_SPACE = spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)


def cpu_us(fns: dict[str, Callable[[], object]], calls: int, blocks: int = 10) -> dict[str, float]:
    """Median thread CPU time per call in µs of each function, in interleaved blocks of calls."""
    for fn in fns.values():
        fn()
    per_call: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(blocks):
        for name, fn in fns.items():
            start = time.thread_time()
            for _ in range(calls):
                fn()
            per_call[name].append((time.thread_time() - start) / calls)
    return {name: 1e6 * statistics.median(v) for name, v in per_call.items()}


class Trajectory:
    """Synthetic steps: episodes of ``EPISODE`` steps, plans of ``L_t`` uniform in ``1..k``."""

    def __init__(self, steps: int, seed: int):
        rng = np.random.default_rng(seed)
        self.obs = rng.standard_normal((steps, OBS_DIM), dtype=np.float32)
        self.next_obs = rng.standard_normal((steps, OBS_DIM), dtype=np.float32)
        self.actions = rng.uniform(-1.0, 1.0, (steps, ACTION_DIM)).astype(np.float32)
        self.rewards = rng.standard_normal(steps, dtype=np.float32)
        self.step = np.arange(steps) % EPISODE  # the first step starts an episode
        self.plans = rng.uniform(-1.0, 1.0, (steps, CHUNK, ACTION_DIM)).astype(np.float32)
        self.new_plan = np.zeros(steps, dtype=bool)
        self.plan_length = np.zeros(steps, dtype=np.int64)
        self.horizon = np.zeros(steps, dtype=np.int32)  # of the plan starting there, 0 if none
        for first in range(0, steps, EPISODE):  # plans restart with every episode
            end = min(first + EPISODE, steps)
            lengths = rng.integers(1, CHUNK + 1, size=end - first)
            starts = first + np.concatenate([[0], np.cumsum(lengths)[:-1]])
            keep = starts < end
            starts, lengths = starts[keep], lengths[keep]
            self.new_plan[starts], self.plan_length[starts] = True, lengths
            self.horizon[starts] = np.minimum(lengths, first + EPISODE - starts)

    def truncated(self, i: int | slice) -> np.ndarray:
        return self.step[i] == EPISODE - 1

    def add_to(self, buf: ChunkReplayBuffer, i: int) -> None:
        buf.add(
            self.obs[i : i + 1], self.next_obs[i : i + 1], self.actions[i : i + 1], self.rewards[i : i + 1],
            np.zeros(1, dtype=bool), self.truncated(slice(i, i + 1)), self.step[i : i + 1] == 0,
            self.new_plan[i : i + 1], self.plans[i : i + 1], self.plan_length[i : i + 1],
        )

    def add_to_sb3(self, buf: ReplayBuffer, i: int) -> None:
        truncated = bool(self.truncated(i))
        buf.add(
            self.obs[i : i + 1], self.next_obs[i : i + 1], self.actions[i : i + 1], self.rewards[i : i + 1],
            np.array([truncated]), [{"TimeLimit.truncated": truncated}],
        )


def chunk_buffer(size: int, traj: Trajectory, fill: str, online_targets: str = "prefix") -> ChunkReplayBuffer:
    """A full ring of ``size`` steps of ``traj`` (which holds a whole number of episodes)."""
    buf = ChunkReplayBuffer(
        size, OBS_SPACE, ACTION_SPACE, "cpu", chunk_size=CHUNK, history_len=HISTORY, offline_ratio=0.5,
        online_targets=online_targets,
    )
    if fill == "add":
        for i in range(size):
            traj.add_to(buf, i)
        return buf
    s, steps = buf.online, traj.step[:size]
    s.obs[:, 0], s.next_obs[:, 0] = traj.obs[:size], traj.next_obs[:size]
    s.actions[:, 0], s.rewards[:, 0] = traj.actions[:size], traj.rewards[:size]
    s.episode_step[:, 0] = steps
    if online_targets == "prefix":
        s.horizon[:, 0] = traj.horizon[:size]
        starts = np.flatnonzero(traj.new_plan[:size])
        s.plans[starts, 0] = traj.plans[starts]
        buf._write_chunks(starts, np.zeros_like(starts), s.horizon[starts, 0])  # as the plans closed
    else:
        s.horizon[:, 0] = np.minimum(CHUNK, EPISODE - steps)
    s.bootstrap[:, 0] = s.horizon[:, 0] > 0  # time limits only: every window bootstraps
    buf.full, buf.pos = True, 0
    buf._next_episode_step[:] = steps[-1] + 1
    buf.reindex()
    return buf


def sb3_buffer(size: int, traj: Trajectory, fill: str) -> ReplayBuffer:
    buf = ReplayBuffer(size, OBS_SPACE, ACTION_SPACE, "cpu")
    if fill == "add":
        for i in range(size):
            traj.add_to_sb3(buf, i)
        return buf
    buf.observations[:, 0], buf.next_observations[:, 0] = traj.obs[:size], traj.next_obs[:size]
    buf.actions[:, 0], buf.rewards[:, 0] = traj.actions[:size], traj.rewards[:size]
    buf.dones[:, 0] = buf.timeouts[:, 0] = traj.truncated(slice(0, size))
    buf.full, buf.pos = True, 0
    return buf


def offline_episodes(traj: Trajectory, steps: int) -> list[dict[str, Any]]:
    out = []
    for first in range(0, steps, EPISODE):
        sl = slice(first, first + EPISODE)
        out.append({
            "observations": traj.obs[sl], "next_observations": traj.next_obs[sl], "actions": traj.actions[sl],
            "rewards": traj.rewards[sl], "terminations": np.zeros(EPISODE, dtype=bool),
            "truncations": traj.truncated(sl),
        })
    return out


def footprint_mb(buf: object) -> float:
    """MB of the NumPy arrays held by ``buf`` and by the objects it holds."""
    total = 0
    for value in vars(buf).values():
        for item in [value, *vars(value).values()] if hasattr(value, "__dict__") else [value]:
            total += item.nbytes if isinstance(item, np.ndarray) else 0
    return total / 2**20


def sample_row(what: str, ours: ChunkReplayBuffer, sb3: ReplayBuffer, calls: int) -> tuple[str, float, float]:
    np.random.seed(0)  # noqa: NPY002 - both buffers sample with NumPy's global RNG (as SB3 seeds it)
    t = cpu_us({"ours": lambda: ours.sample(BATCH), "sb3": lambda: sb3.sample(BATCH)}, calls)
    return what, t["ours"], t["sb3"]


def add_row(ours: ChunkReplayBuffer, sb3: ReplayBuffer, traj: Trajectory, first: int, steps: int):
    """add() of ``steps`` steps of ``traj`` from ``first`` on into both buffers."""
    ours_steps, sb3_steps = iter(range(first, first + steps)), iter(range(first, first + steps))
    fns = {
        "ours": lambda: traj.add_to(ours, next(ours_steps)),
        "sb3": lambda: traj.add_to_sb3(sb3, next(sb3_steps)),
    }
    t = cpu_us(fns, calls=steps // 10 - 1)
    return "add, one step", t["ours"], t["sb3"]


def bench_size(size: int, fill: str, calls: int, add_steps: int) -> list[tuple[str, float, float]]:
    """Rows (what, ours, SB3) at one buffer size."""
    traj = Trajectory(size + add_steps, seed=size)
    sb3 = sb3_buffer(size, traj, fill)
    offline = ChunkReplayBuffer(
        size, OBS_SPACE, ACTION_SPACE, "cpu", chunk_size=CHUNK, history_len=HISTORY, offline_ratio=0.5,
        online_targets="prefix",
    )
    offline.add_offline_episodes(offline_episodes(traj, size))
    rows = [
        sample_row("sample, online (prefix)", chunk_buffer(size, traj, fill), sb3, calls),
        sample_row("sample, online (window)", chunk_buffer(size, traj, fill, "window"), sb3, calls),
        sample_row("sample, offline only", offline, sb3, calls),
    ]
    mixed = chunk_buffer(size, traj, fill)
    mixed.add_offline_episodes(offline_episodes(traj, size))
    rows.append(sample_row("sample, mixed 0.5", mixed, sb3, calls))
    ours = chunk_buffer(size, traj, fill)
    # add() into the full rings, overwriting (the bookkeeping of the valid starts included)
    rows.append(add_row(ours, sb3, traj, size, add_steps))
    kept = ours.online_starts().tolist()
    ours.reindex()
    assert ours.online_starts().tolist() == kept  # the index kept up
    rows.append(("memory (MB), online ring", footprint_mb(ours), footprint_mb(sb3)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--fill", choices=["bulk", "add"], default="bulk")
    parser.add_argument("--calls", type=int, default=30, help="sample() calls per block (10 blocks)")
    parser.add_argument("--add-steps", type=int, default=5_000, help="add() calls measured per buffer")
    args = parser.parse_args()
    th.set_num_threads(1)
    print(
        f"batch {BATCH}, history {HISTORY}, k {CHUNK}, obs dim {OBS_DIM}, action dim {ACTION_DIM}, "
        f"fill {args.fill}; numpy {np.__version__}, torch {th.__version__}, {platform.machine()}, "
        f"{time.strftime('%Y-%m-%d %H:%M')}"
    )
    print(f"{'size':>9} | {'what':<26} | {'ours':>10} | {'SB3':>10} | {'ours/SB3':>8}")
    for size in args.sizes:
        for what, ours, sb3 in bench_size(size, args.fill, args.calls, args.add_steps):
            unit = "" if what.startswith("memory") else " µs"
            row = f"{size:>9} | {what:<26} | {ours:>7.1f}{unit:3} | {sb3:>7.1f}{unit:3} | {ours / sb3:>8.2f}"
            print(row, flush=True)


if __name__ == "__main__":
    main()
