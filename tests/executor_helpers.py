"""Top-level unit functions for the executor tests (importable by spawned processes and Ray workers)."""

from __future__ import annotations

import os

import numpy as np


def square(x: int) -> dict[str, int]:
    return {"x": x, "square": x * x}


def process_id() -> int:
    return os.getpid()


def fail(message: str) -> None:
    raise ValueError(message)


def sumo_episode(seed: int, accel: float = 1.0, time_limit: float = 2.0) -> dict[str, float]:
    """A short MixedTraffic-v0 episode at constant acceleration: its return and length (uses libsumo)."""
    from sb3_ua2c.offline import make_env

    env = make_env(env_kwargs={"time_limit": time_limit})
    try:
        env.reset(seed=seed)
        total, steps, done = 0.0, 0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(np.array([accel, 0.0], dtype=np.float32))
            total += float(reward)
            steps += 1
            done = terminated or truncated
        return {"reward": total, "steps": steps}
    finally:
        env.close()
