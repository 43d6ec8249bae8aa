"""``OGBenchSingleTask-v0``: an OGBench single-task environment as OGBench builds it, shaped for SB3."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from experiments.ogbench.data import TaskName, sparse_reward
from sb3_ua2c.checks import check_int

ENV_ID = "OGBenchSingleTask-v0"


class OGBenchSingleTask(gym.Env):
    """OGBench single-task environment with a float32 Box observation and ``info["success"]``; ``sparse``: the
    reward of Q-chunking's ``--sparse``; ``max_episode_steps``: a shorter time limit than OGBench's."""

    metadata = {"render_modes": []}

    def __init__(self, task: str = "cube-single-play-singletask-task2-v0", sparse: bool = False,
                 max_episode_steps: int | None = None) -> None:
        import ogbench

        TaskName.parse(task)
        if not isinstance(sparse, bool):
            raise TypeError(f"sparse must be a bool, got {type(sparse).__name__}")
        limit = {}
        if max_episode_steps is not None:
            check_int("max_episode_steps", max_episode_steps)
            limit["max_episode_steps"] = max_episode_steps
        self.task, self.sparse = task, sparse
        self._env = ogbench.make_env_and_datasets(task, env_only=True, **limit)
        inner = self._env.observation_space
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=inner.shape, dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=self._env.action_space.shape, dtype=np.float32)
        self.max_episode_steps = self._env.spec.max_episode_steps

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        obs, info = self._env.reset(seed=seed, options=options)
        return obs.astype(np.float32), self._info(info, False)

    def step(self, action: np.ndarray):
        obs, reward, terminated, truncated, info = self._env.step(np.asarray(action, dtype=np.float64))
        success = bool(info.get("success", False))
        if self.sparse:
            reward = float(sparse_reward(np.asarray([reward]))[0])
        return obs.astype(np.float32), float(reward), bool(terminated), bool(truncated), self._info(info, success)

    def _info(self, info: dict[str, Any], success: bool) -> dict[str, Any]:
        """Only what a learner reads: success and the physical state (from the simulator when ``info`` lacks it)."""
        qpos = info["qpos"] if "qpos" in info else self._env.unwrapped.data.qpos
        return {"success": success, "qpos": np.asarray(qpos).copy()}

    def close(self) -> None:
        self._env.close()


def register() -> None:
    """Register :data:`ENV_ID` with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="experiments.ogbench.env:OGBenchSingleTask")
