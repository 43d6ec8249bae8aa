"""Small UA2C settings shared by the algorithm tests (seconds per test on one core)."""

import hashlib

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_ua2c.policies import UA2CPolicy

#: 1-dim observation and action spaces of the hand-computed buffer, target and execution tests
OBS = spaces.Box(-np.inf, np.inf, (1,), np.float32)
ACT = spaces.Box(-1.0, 1.0, (1,), np.float32)
#: tiny networks
TINY = dict(net_arch=[32, 32], critic_kwargs=dict(embed_dim=16, ff_dim=32))
#: tiny networks, short warm-up, few candidates
FAST = dict(
    policy_kwargs=TINY,
    learning_starts=50,
    batch_size=16,
    buffer_size=1000,
    flow_steps=3,
    n_candidates=4,
    n_target_candidates=2,
)


def tiny_policy(n_candidates: int = 6, **kwargs) -> UA2CPolicy:
    """A policy with 3-dim observations, 2-dim actions in [-1, 1], k = 3, ℓ = 2 and tiny networks."""
    if kwargs.get("critic_arch", "transformer") == "transformer":
        kwargs.setdefault("critic_kwargs", dict(embed_dim=8, ff_dim=16))
    return UA2CPolicy(
        spaces.Box(-5.0, 5.0, (3,), dtype=np.float32),
        spaces.Box(-1.0, 1.0, (2,), dtype=np.float32),
        lambda _: 1e-3,
        chunk_size=3,
        history_len=2,
        n_candidates=n_candidates,
        flow_steps=2,
        net_arch=[16],
        **kwargs,
    )


def rollout_actions(model, n: int = 12, deterministic: bool = True) -> np.ndarray:
    """The actions of ``n`` consecutive Pendulum-v1 steps (reset seed 3) carrying the executor state."""
    env = gym.make("Pendulum-v1")
    obs, _ = env.reset(seed=3)
    state, start, out = None, np.array([True]), []
    for _ in range(n):
        action, state = model.predict(obs, state=state, episode_start=start, deterministic=deterministic)
        out.append(action)
        obs, *_ = env.step(action)
        start = np.array([False])
    return np.array(out)


def model_objective(model, data, q_weight=None, generator=None):
    """The actor objective a model trains with, on ``data`` (``q_weight=None``: the model's)."""
    from sb3_ua2c.actors import actor_objective

    policy = model.policy
    return actor_objective(policy.actor_type, policy.actor_inputs(), data, model.actor_weights(q_weight), generator)


def state_hash(model) -> str:
    """SHA-256 of a model's policy state dict (keys and float bytes): equal only when every weight is."""
    h = hashlib.sha256()
    for key, value in model.policy.state_dict().items():
        h.update(key.encode())
        h.update(value.detach().cpu().numpy().tobytes())
    return h.hexdigest()
