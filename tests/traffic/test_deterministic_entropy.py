"""Deterministic acting without bias, on a trained checkpoint (the shipped Phase-1 checkpoint of
MixedTraffic-v0): at the histories of a driven episode, the entropies ``H_u`` of the deterministic
(history-seeded) noise agree with those of fresh noise within the estimator's error, and so do the
executed lengths of a rule that depends on them; one noise draw shared by every history is biased."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_ua2c import UA2C
from sb3_ua2c.chunking import chunk_entropy, executable_prefix_length, quantile_entropy_thresholds

CHECKPOINT = Path(__file__).resolve().parents[2] / "rl-trained-agents" / "ua2c" / "MixedTraffic-v0_1" / "MixedTraffic-v0.zip"


@pytest.fixture(scope="module")
def histories():
    """The checkpoint and the (observation, action) histories of every step of one driven episode."""
    from envs.collection import make_traffic_env

    model = UA2C.load(CHECKPOINT, device="cpu")
    env = make_traffic_env("MixedTraffic-v0", None, "default")
    try:
        obs, _ = env.reset(seed=7)
        state, obs_h, act_h, done = None, [], [], False
        while not done:
            action, state = model.predict(obs, state=state, deterministic=True)
            obs_h.append(state.observation_history[0])
            act_h.append(state.action_history[0])
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    finally:
        env.close()
    return model, th.as_tensor(np.stack(obs_h)), th.as_tensor(np.stack(act_h))


def _entropy(policy, obs_h, act_h, x0):
    """``H_u`` ``(m, k)`` of the clipped candidates sampled from noise ``x0`` ``(1 or m, S, k, A)``."""
    with th.inference_mode():
        x0 = x0.expand(obs_h.shape[0], -1, -1, -1)
        samples = policy.sample_chunks(obs_h, act_h, x0.shape[1], policy.flow_steps, x0=x0)
        return chunk_entropy(samples.clamp(-1.0, 1.0), policy.discrete_dims, discrete=policy.discrete_entropy)


def test_deterministic_and_fresh_noise_give_the_same_entropies_and_lengths(histories):
    model, obs_h, act_h = histories
    policy = model.policy
    m, s, k, a = obs_h.shape[0], policy.n_candidates, policy.chunk_size, policy.action_dim
    assert m >= 50
    with th.inference_mode():
        _, det_lengths, det = policy.plan_tensors(obs_h, act_h, deterministic=True)
    th.manual_seed(0)
    fresh = th.stack([_entropy(policy, obs_h, act_h, th.randn(m, s, k, a)) for _ in range(8)])  # (8, m, k)
    # per position, the mean over the episode: fresh noise's own spread between draws sets the tolerance
    offset = (det - fresh.mean(0)).mean(0)  # (k,)
    spread = fresh.mean(1).std(0, correction=1)  # (k,) SD of one draw's episode mean
    assert th.all(offset.abs() < 0.05), (offset, spread)
    # the lengths of a rule that reads H_u: the median of fresh H_u per position as δ_u
    thresholds = quantile_entropy_thresholds(fresh.flatten(0, 1), 0.5)
    fresh_lengths = executable_prefix_length(fresh, thresholds).float().mean(1)  # (8,)
    det_mean = executable_prefix_length(det, thresholds).float().mean()
    assert 1.3 < float(fresh_lengths.mean()) < k - 0.3  # the rule does cut
    assert abs(float(det_mean - fresh_lengths.mean())) < 3 * float(fresh_lengths.std()) + 0.1
    # one draw shared by every history (the rule before 2026-12-04): its own luck shows in H_u (the test can fail)
    shared = th.randn((1, s, k, a), generator=th.Generator().manual_seed(0))
    shared_offset = (_entropy(policy, obs_h, act_h, shared) - fresh.mean(0)).mean(0)
    assert shared_offset.abs().max() > 0.1, shared_offset
    assert det_lengths.shape == (m,)
