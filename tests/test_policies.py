"""UA2CPolicy's replanning: which chunk a replanning executes (best-of-S or elite mean)."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_ua2c.policies import UA2CPolicy


def make_policy(**kwargs) -> UA2CPolicy:
    return UA2CPolicy(
        spaces.Box(-5.0, 5.0, (3,), dtype=np.float32),
        spaces.Box(-1.0, 1.0, (2,), dtype=np.float32),
        lambda _: 1e-3,
        chunk_size=3,
        history_len=2,
        n_candidates=6,
        flow_steps=2,
        net_arch=[16],
        critic_embed_dim=8,
        critic_ff_dim=16,
        **kwargs,
    )


def candidates_and_values(policy: UA2CPolicy, obs_h: th.Tensor, act_h: th.Tensor, seed: int):
    """The replanning's S candidates (clipped) and their ``min_j Q_j``, recomputed by hand."""
    cond = policy.actor.condition(policy.flatten_history(obs_h, act_h))
    samples = policy.sample_chunks(cond, 6, 2, th.Generator().manual_seed(seed)).clamp(-1.0, 1.0)
    return samples, policy.critic(obs_h.reshape(obs_h.shape[0], -1), samples).min(dim=0).values  # (m, S)


@pytest.mark.parametrize("n_elite", [0, 7, 2.5])
def test_policy_rejects_bad_elite_size(n_elite):
    with pytest.raises(ValueError, match="n_elite"):
        make_policy(n_elite=n_elite)


def test_plan_executes_the_best_candidate_by_default():
    th.manual_seed(0)
    policy = make_policy()
    obs_h, act_h = th.randn(4, 2, 3), th.zeros(4, 2, 2)
    chunks, _, _ = policy.plan_tensors(obs_h, act_h, th.Generator().manual_seed(5))
    samples, q = candidates_and_values(policy, obs_h, act_h, 5)
    assert th.equal(chunks, samples[th.arange(4), q.argmax(dim=1)])


def test_plan_with_elite_mean():
    th.manual_seed(0)
    policy = make_policy(n_elite=3, discrete_dims={1: 3})
    obs_h, act_h = th.randn(2, 2, 3), th.zeros(2, 2, 2)
    chunks, _, _ = policy.plan_tensors(obs_h, act_h, th.Generator().manual_seed(5))
    samples, q = candidates_and_values(policy, obs_h, act_h, 5)
    top = q.topk(3, dim=1).indices
    for i in range(2):  # acceleration: mean of the 3 best; lane change: the best candidate's
        assert th.allclose(chunks[i, :, 0], samples[i, top[i], :, 0].mean(dim=0))
        assert th.equal(chunks[i, :, 1], samples[i, top[i, 0], :, 1])


def test_discrete_entropy_flag_changes_only_the_prefix_length():
    """H_u with and without the categorical dim: same chunks, entropies differ by the categorical part."""
    th.manual_seed(0)
    with_cat = make_policy(discrete_dims={1: 3})
    without = make_policy(discrete_dims={1: 3}, discrete_entropy=False)
    without.load_state_dict(with_cat.state_dict())
    obs_h, act_h = th.randn(4, 2, 3), th.zeros(4, 2, 2)
    g = lambda: th.Generator().manual_seed(3)  # noqa: E731
    chunks_a, _, h_a = with_cat.plan_tensors(obs_h, act_h, g())
    chunks_b, _, h_b = without.plan_tensors(obs_h, act_h, g())
    assert th.equal(chunks_a, chunks_b)
    cond = with_cat.actor.condition(with_cat.flatten_history(obs_h, act_h))
    samples = with_cat.sample_chunks(cond, 6, 2, g())  # (m, S, k, A)
    from sb3_ua2c.chunking import categorical_entropy, categorize

    assert th.allclose(h_a - h_b, categorical_entropy(categorize(samples[..., 1], 3), 3).float(), atol=1e-6)
    assert without._get_constructor_parameters()["discrete_entropy"] is False


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_policy_rejects_non_bool_discrete_entropy(bad):
    with pytest.raises(ValueError, match="discrete_entropy"):
        make_policy(discrete_entropy=bad)


def test_commit_discrete_extends_only_the_prefix_length():
    """Same chunks and entropies; L_t becomes commit_through_switch(L_t of Eq. 7, the selected chunk)."""
    from sb3_ua2c.chunking import commit_through_switch

    th.manual_seed(0)
    plain = make_policy(discrete_dims={1: 3}, entropy_threshold=-10.0)  # Eq. 7 alone gives L_t = 1
    commit = make_policy(discrete_dims={1: 3}, entropy_threshold=-10.0, commit_discrete=True)
    commit.load_state_dict(plain.state_dict())
    obs_h, act_h = th.randn(16, 2, 3), th.zeros(16, 2, 2)
    g = lambda: th.Generator().manual_seed(3)  # noqa: E731
    chunks_a, len_a, h_a = plain.plan_tensors(obs_h, act_h, g())
    chunks_b, len_b, h_b = commit.plan_tensors(obs_h, act_h, g())
    assert th.equal(chunks_a, chunks_b) and th.equal(h_a, h_b)
    assert len_a.tolist() == [1] * 16
    assert th.equal(len_b, commit_through_switch(len_a, chunks_a, {1: 3}))
    assert (len_b > 1).any()  # some of the 16 selected chunks switch lanes: the test can fail
    assert commit._get_constructor_parameters()["commit_discrete"] is True


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_policy_rejects_non_bool_commit_discrete(bad):
    with pytest.raises(ValueError, match="commit_discrete"):
        make_policy(commit_discrete=bad)
