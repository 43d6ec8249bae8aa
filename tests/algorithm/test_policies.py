"""UA2CPolicy's replanning: which chunk a replanning executes (best-of-S or elite mean), and
deterministic plans that do not depend on the batch."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv
from ua2c_helpers import FAST, tiny_policy

from sb3_ua2c import UA2C
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.policies import UA2CPolicy


def make_policy(**kwargs) -> UA2CPolicy:
    return tiny_policy(**kwargs)


def candidates_and_values(policy: UA2CPolicy, obs_h: th.Tensor, act_h: th.Tensor, seed: int):
    """The replanning's S candidates (clipped) and their ``min_j Q_j``, recomputed by hand."""
    samples = policy.sample_chunks(obs_h, act_h, 6, 2, th.Generator().manual_seed(seed)).clamp(-1.0, 1.0)
    return samples, policy.critic(obs_h.reshape(obs_h.shape[0], -1), samples).min(dim=0).values  # (m, S)


@pytest.mark.parametrize("n_elite", [0, 7, 2.5])
def test_policy_rejects_bad_elite_size(n_elite):
    with pytest.raises(ValueError, match="n_elite"):
        make_policy(n_elite=n_elite)


def test_default_n_elite_is_eight_or_every_candidate_when_fewer():
    assert make_policy(n_candidates=32).n_elite == 8 and make_policy(n_candidates=6).n_elite == 6
    assert make_policy(n_candidates=6, n_elite=1).n_elite == 1


def test_plan_executes_the_best_candidate_with_n_elite_1():
    th.manual_seed(0)
    policy = make_policy(n_elite=1)
    obs_h, act_h = th.randn(4, 2, 3), th.zeros(4, 2, 2)
    chunks, _, _ = policy.plan_tensors(obs_h, act_h, th.Generator().manual_seed(5))
    samples, q = candidates_and_values(policy, obs_h, act_h, 5)
    assert th.equal(chunks, samples[th.arange(4), q.argmax(dim=1)])


def test_plan_with_elite_mean():
    th.manual_seed(0)
    policy = make_policy(n_elite=3, discrete_action_dims={1: [-1.0, 0.0, 1.0]})
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
    with_cat = make_policy(discrete_action_dims={1: [-1.0, 0.0, 1.0]})
    without = make_policy(discrete_action_dims={1: [-1.0, 0.0, 1.0]}, discrete_entropy=False)
    without.load_state_dict(with_cat.state_dict())
    obs_h, act_h = th.randn(4, 2, 3), th.zeros(4, 2, 2)
    g = lambda: th.Generator().manual_seed(3)  # noqa: E731
    chunks_a, _, h_a = with_cat.plan_tensors(obs_h, act_h, g())
    chunks_b, _, h_b = without.plan_tensors(obs_h, act_h, g())
    assert th.equal(chunks_a, chunks_b)
    samples = with_cat.sample_chunks(obs_h, act_h, 6, 2, g())  # (m, S, k, A)
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
    plain = make_policy(discrete_action_dims={1: [-1.0, 0.0, 1.0]}, execution=ExecutionRule(entropy_threshold=-10.0))  # Eq. 7 alone gives L_t = 1
    commit = make_policy(discrete_action_dims={1: [-1.0, 0.0, 1.0]}, execution=ExecutionRule(entropy_threshold=-10.0),
                         commit_discrete=True)
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


# ---------------------------------------------------------------- deterministic predict on a batch
#: deterministic plans are made one history at a time, so a row's actions match bit for bit in any batch;
#: ``forward`` against ``predict`` differ by the rounding of the unscaling of the actions
ROUNDING = 1e-5


def batch_policy(chunk_size: int) -> UA2CPolicy:
    """A policy whose executable length ``L_t`` varies with the history for ``k = 3``."""
    th.manual_seed(0)
    return UA2CPolicy(
        spaces.Box(-5.0, 5.0, (3,), dtype=np.float32),
        spaces.Box(-2.0, 2.0, (2,), dtype=np.float32),
        lambda _: 1e-3,
        chunk_size=chunk_size,
        history_len=2,
        n_candidates=6,
        flow_steps=2,
        execution=ExecutionRule(entropy_threshold=2.41),
        net_arch=[16],
        critic_kwargs=dict(embed_dim=8, ff_dim=16),
    )


def stateful_rollout(policy: UA2CPolicy, obs: np.ndarray, starts: np.ndarray):
    """Deterministic actions ``(T, R, A)`` and plan lengths ``(T, R)`` of ``R`` envs fed ``obs`` ``(T, R, obs_dim)``."""
    state, actions, lengths = None, [], []
    for o, s in zip(obs, starts, strict=True):
        a, state = policy.predict(o, state=state, episode_start=s, deterministic=True)
        actions.append(a)
        lengths.append(state.plan_length)
    return np.array(actions), np.array(lengths)


@pytest.mark.parametrize("chunk_size", [1, 3])
def test_deterministic_predict_of_identical_rows_in_one_batch(chunk_size):
    policy = batch_policy(chunk_size)
    obs = np.array([0.5, -1.0, 2.0], np.float32)
    alone, _ = policy.predict(obs, deterministic=True)
    batch, _ = policy.predict(np.tile(obs, (5, 1)), deterministic=True)
    np.testing.assert_array_equal(batch, np.tile(alone, (5, 1)))
    with th.inference_mode():
        forward = policy(th.as_tensor(np.tile(obs, (5, 1))), deterministic=True)
    np.testing.assert_allclose(policy.unscale_action(forward.numpy()), batch, rtol=0, atol=ROUNDING)


@pytest.mark.parametrize("chunk_size", [1, 3])
def test_deterministic_predict_row_is_independent_of_the_batch(chunk_size):
    """A row's action alone, in a batch of 5 with other rows, and with the rows permuted."""
    policy = batch_policy(chunk_size)
    obs = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    alone = np.array([policy.predict(o, deterministic=True)[0] for o in obs])
    batch, _ = policy.predict(obs, deterministic=True)
    perm = np.array([3, 0, 4, 1, 2])
    permuted, _ = policy.predict(obs[perm], deterministic=True)
    np.testing.assert_array_equal(batch, alone)
    np.testing.assert_array_equal(permuted, alone[perm])
    assert np.abs(alone[:, None] - alone[None]).max() > 0.1  # the rows do act differently


@pytest.mark.parametrize("chunk_size", [1, 3])
def test_deterministic_stateful_predict_row_is_independent_of_the_batch(chunk_size):
    """Five envs carrying ``state``, episodes starting at different steps: each env's actions and
    ``L_t`` are those it gets alone, and in a permuted batch, although its replannings share calls
    with different sets of other envs."""
    policy = batch_policy(chunk_size)
    n_steps, n_envs = 12, 5
    obs = np.random.default_rng(1).normal(size=(n_steps, n_envs, 3)).astype(np.float32)
    starts = np.zeros((n_steps, n_envs), dtype=bool)
    starts[0] = True
    for env, t in enumerate([5, 2, 7, 4, 9]):  # a second episode per env
        starts[t, env] = True
    batch, batch_len = stateful_rollout(policy, obs, starts)
    for env in range(n_envs):
        alone, alone_len = stateful_rollout(policy, obs[:, env : env + 1], starts[:, env : env + 1])
        np.testing.assert_array_equal(batch[:, env], alone[:, 0])
        np.testing.assert_array_equal(batch_len[:, env], alone_len[:, 0])
    perm = np.array([2, 4, 0, 3, 1])
    permuted, permuted_len = stateful_rollout(policy, obs[:, perm], starts[:, perm])
    np.testing.assert_array_equal(permuted, batch[:, perm])
    np.testing.assert_array_equal(permuted_len, batch_len[:, perm])
    if chunk_size > 1:  # adaptive chunks: envs replan at different steps, so calls mix different rows
        assert len(np.unique(batch_len)) > 1


def test_evaluate_policy_with_several_envs_gives_each_env_its_own_returns():
    """``evaluate_policy`` on 3 envs: each env's episode return is the one it gets evaluated alone."""
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, entropy_threshold=1.5, **FAST)

    def returns(seeds: list[int]) -> list[float]:
        env = DummyVecEnv([lambda: gym.make("Pendulum-v1", max_episode_steps=40)] * len(seeds))
        env.seed(seeds[0])  # env i gets seed seeds[0] + i
        rewards, _ = evaluate_policy(model, env, len(seeds), deterministic=True, return_episode_rewards=True, warn=False)
        return rewards

    together = returns([5, 6, 7])  # one episode per env, in the order they end (all after 40 steps)
    alone = [returns([seed])[0] for seed in (5, 6, 7)]
    np.testing.assert_allclose(together, alone, rtol=1e-5)
    assert min(alone) < max(alone) - 1.0  # the envs do differ
