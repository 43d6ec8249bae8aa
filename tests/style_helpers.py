"""Shared helpers of the style tests: a generated labelled dataset and a fake slot environment."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.style import SLOT_FEATURES, SLOT_NAMES, StyleDataset, valid_mask

# per style (conservative, neutral, aggressive): time headway [s], accel noise std [m/s²]
_HEADWAY = (2.2, 1.5, 0.9)
_ACCEL_STD = (0.3, 0.6, 1.2)


def make_generated_dataset(
    n_episodes: int = 12, per_episode: int = 60, seq_len: int = 10, seed: int = 0
) -> StyleDataset:
    """Sequences whose style shows in the time headway and the acceleration noise, blurred by
    per-step noise so a single token is ambiguous but the sequence is informative."""
    rng = np.random.default_rng(seed)
    n = n_episodes * per_episode
    labels = rng.integers(0, 3, n)
    lengths = rng.integers(1, seq_len + 1, n)
    speed = rng.uniform(15.0, 30.0, (n, 1)) + rng.normal(0.0, 0.3, (n, seq_len)).cumsum(1)
    headway = np.take(_HEADWAY, labels)[:, None] + rng.normal(0.0, 0.6, (n, seq_len))
    accel = rng.normal(0.0, 1.0, (n, seq_len)) * np.take(_ACCEL_STD, labels)[:, None]
    tokens = np.zeros((n, seq_len, len(SLOT_FEATURES)), dtype=np.float32)
    tokens[..., 0] = rng.uniform(-30, 30, (n, 1))  # dp
    tokens[..., 1] = rng.normal(0.0, 2.0, (n, seq_len))  # dv
    tokens[..., 2] = accel
    tokens[..., 3] = speed
    tokens[..., 4] = rng.integers(-1, 2, (n, 1))  # lane offset
    tokens[..., 5] = np.clip(speed * headway, 2.0, 100.0)  # gap to leader
    tokens[..., 6] = rng.uniform(10.0, 60.0, (n, 1))  # lane density
    valid = valid_mask(lengths, seq_len)
    tokens[~valid] = 0.0
    episodes = np.repeat(np.arange(n_episodes), per_episode)
    slots = rng.integers(0, len(SLOT_NAMES), n)
    return StyleDataset(tokens, valid, labels, episodes, slots, {"generator": "tests"})


class FakeSlotEnv(gym.Env):
    """Tiny env honouring the ``info["slots"]`` contract of ``MixedTraffic-v0``: 20 observations,
    Box(2) actions; slot 2 (l_3) is always empty, slot 0 (l_1) changes occupant every 4 steps."""

    metadata = {"render_modes": []}

    def __init__(self, episode_length: int = 30):
        self.observation_space = spaces.Box(-10.0, 10.0, (20,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.episode_length = episode_length
        self._t = 0

    def _info(self) -> dict:
        present = np.array([True, True, False, True, True, True])
        ids = tuple(
            "" if not p else (f"hdv{self._t // 4}" if m == 0 else f"veh{m}") for m, p in enumerate(present)
        )
        features = self.np_random.normal(0.0, 1.0, (6, len(SLOT_FEATURES))).astype(np.float32)
        features[~present] = 0.0
        styles = np.where(present, np.arange(6) % 3, -1).astype(np.int64)
        return {"slots": {"ids": ids, "styles": styles, "features": features, "present": present}}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._t = 0
        return self.np_random.normal(size=20).clip(-10, 10).astype(np.float32), self._info()

    def step(self, action):
        self._t += 1
        obs = self.np_random.normal(size=20).clip(-10, 10).astype(np.float32)
        return obs, 0.0, False, self._t >= self.episode_length, self._info()
