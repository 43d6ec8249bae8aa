"""The chunk critics' horizon (Eq. 8 semantics) and the flow's source noise, against hand-computed values."""

import math

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_ua2c.flow import chunk_noise
from sb3_ua2c.policies import ChunkCritics, UA2CPolicy, horizon_token_mask


def critics(k: int = 4, n_heads: int = 1) -> ChunkCritics:
    th.manual_seed(0)
    return ChunkCritics(6, k, 2, n_critics=2, embed_dim=8, n_layers=2, n_heads=n_heads, ff_dim=16)


def test_horizon_token_mask_hand_computed():
    mask = horizon_token_mask(th.tensor([1.0, 3.0]), chunk_size=3, n_candidates=2)
    # token 0 is the observation history, token u + 1 the action a_{t+u}: kept iff u < L
    expected = th.tensor(
        [[True, True, False, False], [True, True, False, False], [True, True, True, True], [True, True, True, True]]
    )
    assert th.equal(mask, expected)


@pytest.mark.parametrize("n_heads", [1, 2])
def test_critic_ignores_the_tail_beyond_the_horizon(n_heads):
    net = critics(n_heads=n_heads)
    obs = th.randn(3, 6)
    chunks = th.randn(3, 5, 4, 2)  # (B, C, k, A)
    horizon = th.tensor([1, 2, 4])
    q = net(obs, chunks, horizon)
    changed = chunks.clone()
    changed[0, :, 1:] = 7.0  # after L = 1
    changed[1, :, 2:] = -3.0  # after L = 2
    assert th.allclose(net(obs, changed, horizon), q, atol=1e-6)
    # ... but an action inside the prefix changes the value
    inside = chunks.clone()
    inside[1, :, 1] += 1.0
    assert not th.allclose(net(obs, inside, horizon)[:, 1], q[:, 1])
    # the same history with L = 4 sees the tail
    assert not th.allclose(net(obs, changed, th.tensor([4, 4, 4]))[:, :2], net(obs, chunks)[:, :2])


def test_full_horizon_is_the_whole_chunk_bit_for_bit():
    net = critics()
    obs, chunks = th.randn(3, 6), th.randn(3, 5, 4, 2)
    assert th.equal(net(obs, chunks, th.full((3,), 4.0)), net(obs, chunks))


def test_masked_critic_trains_without_nan_gradients():
    net = critics()
    obs, chunks = th.randn(3, 6), th.randn(3, 1, 4, 2, requires_grad=True)
    net(obs, chunks, th.tensor([1, 2, 3])).sum().backward()
    assert all(th.isfinite(p.grad).all() for p in net.parameters() if p.grad is not None)
    assert th.equal(chunks.grad[0, 0, 1:], th.zeros(3, 2))  # no gradient reaches the tail
    assert chunks.grad[0, 0, 0].abs().sum() > 0


def test_chunk_noise_without_correlation_is_randn():
    g1, g2 = th.Generator().manual_seed(3), th.Generator().manual_seed(3)
    assert th.equal(chunk_noise((2, 5, 3), 0.0, g1), th.randn((2, 5, 3), generator=g2))


def test_chunk_noise_hand_computed():
    g1, g2 = th.Generator().manual_seed(1), th.Generator().manual_seed(1)
    z = th.randn((2, 3, 1), generator=g2)
    shared = th.randn((2, 1, 1), generator=g2)
    # x0 = sqrt(0.64) z_shared + sqrt(0.36) z_u = 0.8 z_shared + 0.6 z_u
    assert th.allclose(chunk_noise((2, 3, 1), 0.64, g1), 0.8 * shared + 0.6 * z)


def test_chunk_noise_statistics():
    x = chunk_noise((200_000, 2, 1), 0.9, th.Generator().manual_seed(0)).squeeze(-1)  # (N, k=2)
    assert x.var(dim=0).numpy() == pytest.approx([1.0, 1.0], abs=0.02)
    assert np.corrcoef(x.T.numpy())[0, 1] == pytest.approx(0.9, abs=0.01)
    # the step change inside a chunk has variance 2 (1 - rho) = 0.2 instead of 2
    assert (x[:, 1] - x[:, 0]).var().item() == pytest.approx(0.2, abs=0.01)


@pytest.mark.parametrize("rho", [-0.1, 1.0, math.nan])
def test_chunk_noise_rejects_bad_correlation(rho):
    with pytest.raises(ValueError, match="noise_correlation"):
        chunk_noise((1, 2, 1), rho)


def make_policy(**kwargs) -> UA2CPolicy:
    space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
    return UA2CPolicy(
        spaces.Box(-5.0, 5.0, (3,), dtype=np.float32), space, lambda _: 1e-3, chunk_size=3, history_len=2,
        n_candidates=6, flow_steps=2, net_arch=[16], critic_embed_dim=8, critic_ff_dim=16, **kwargs,
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(noise_correlation=1.0), "noise_correlation"),
        (dict(noise_correlation=-0.5), "noise_correlation"),
        (dict(noise_correlation="high"), "noise_correlation"),
        (dict(select_by_prefix="yes"), "select_by_prefix"),
    ],
)
def test_policy_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_policy(**kwargs)


@pytest.mark.parametrize("select_by_prefix", [False, True])
def test_plan_selects_by_the_value_of_the_prefix(select_by_prefix):
    th.manual_seed(0)
    policy = make_policy(entropy_threshold=-math.inf if select_by_prefix else 0.0, select_by_prefix=select_by_prefix)
    obs_h, act_h = th.randn(4, 2, 3), th.zeros(4, 2, 2)
    chunks, lengths, _ = policy.plan_tensors(obs_h, act_h, th.Generator().manual_seed(5))
    # the same candidates again, ranked by hand
    cond = policy.actor.condition(policy.flatten_history(obs_h, act_h))
    samples = policy.sample_chunks(cond, 6, 2, th.Generator().manual_seed(5)).clamp(-1.0, 1.0)
    horizon = lengths if select_by_prefix else None
    q = policy.critic(obs_h.reshape(4, -1), samples, horizon).min(dim=0).values  # (m, S)
    assert th.equal(chunks, samples[th.arange(4), q.argmax(dim=1)])
    if select_by_prefix:
        assert th.equal(lengths, th.ones(4, dtype=lengths.dtype))  # delta = -inf: L_t = 1
        full = policy.critic(obs_h.reshape(4, -1), samples).min(dim=0).values
        assert not th.equal(q.argmax(dim=1), full.argmax(dim=1))  # the ranking really changed


def test_policy_rejects_elite_larger_than_candidates():
    with pytest.raises(ValueError, match="n_elite"):
        make_policy(n_elite=7)
    with pytest.raises(ValueError, match="n_elite"):
        make_policy(n_elite=0)


def test_plan_with_elite_mean():
    th.manual_seed(0)
    policy = make_policy(n_elite=3)
    obs_h, act_h = th.randn(2, 2, 3), th.zeros(2, 2, 2)
    chunks, _, _ = policy.plan_tensors(obs_h, act_h, th.Generator().manual_seed(5))
    cond = policy.actor.condition(policy.flatten_history(obs_h, act_h))
    samples = policy.sample_chunks(cond, 6, 2, th.Generator().manual_seed(5)).clamp(-1.0, 1.0)
    q = policy.critic(obs_h.reshape(2, -1), samples).min(dim=0).values
    top = q.topk(3, dim=1).indices
    assert th.allclose(chunks, th.stack([samples[i, top[i]].mean(dim=0) for i in range(2)]))
