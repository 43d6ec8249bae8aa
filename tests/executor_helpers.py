"""Top-level unit functions for the executor tests (importable by spawned processes and Ray workers)."""

from __future__ import annotations

import os

import numpy as np


def square(x: int) -> dict[str, int]:
    return {"x": x, "square": x * x, "pid": os.getpid()}


def process_id() -> int:
    return os.getpid()


def fail(message: str) -> None:
    raise ValueError(message)


def sumo_episode(seed: int, accel: float = 1.0, time_limit: float = 2.0) -> dict[str, float]:
    """A short MixedTraffic-v0 episode at constant acceleration: its return and length (uses libsumo)."""
    from envs.collection import make_traffic_env

    env = make_traffic_env(env_kwargs={"time_limit": time_limit})
    try:
        env.reset(seed=seed)
        total, steps, done = 0.0, 0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(np.array([accel, 0.0], dtype=np.float32))
            total += float(reward)
            steps += 1
            done = terminated or truncated
        return {"reward": total, "steps": steps, "pid": os.getpid()}
    finally:
        env.close()


def demo_units(dataset: str, out: str) -> list:
    """The units the Ray test runs on a real cluster and compares with a local run: plain functions,
    two SUMO episodes and a tiny SAC peer unit on ``dataset`` (written under ``out``)."""
    from experiments.common.runner import Unit
    from experiments.peers import run_sb3_online
    from experiments.peers.common import ArmInputs

    sac = {"inputs": ArmInputs(f"{out}/sac", dataset, seed=1, online_steps=20, eval_seeds=(2001,), eval_episodes=1),
           "hyperparams": {"learning_starts": 5, "batch_size": 8, "policy_kwargs": {"net_arch": [16]}}}
    return [Unit("sq3", square, {"x": 3}), Unit("sumo0", sumo_episode, {"seed": 0}),
            Unit("sumo1", sumo_episode, {"seed": 1, "accel": -1.0}), Unit("sac", run_sb3_online, sac)]


def run_demo_on_ray(address: str, dataset: str, out: str, out_file: str) -> None:
    """Run :func:`demo_units` through :class:`~experiments.common.runner.RayExecutor` and write their values
    as JSON (the driver of the Ray test, run inside the cluster's namespace)."""
    import json

    from experiments.common.runner import RayExecutor, run_units

    results = run_units(demo_units(dataset, out), RayExecutor(address), printer=None)
    with open(out_file, "w") as f:
        json.dump({r.name: r.value for r in results}, f)


def torch_threads() -> int:
    """torch's intra-op threads in the process that runs the unit."""
    import torch

    return torch.get_num_threads()
