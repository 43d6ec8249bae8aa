"""Chunk maths: entropies and executed length (Eq. 7), chunk selection, targets and critic loss (Eq. 3, 4, 8)."""

import math

import pytest
import torch as th

from sb3_ua2c.chunking import (
    ENTROPY_EPS,
    bootstrap_value,
    categorical_entropy,
    categorize,
    chunk_critic_loss,
    chunk_entropy,
    chunk_target,
    commit_through_switch,
    discounted_chunk_return,
    executable_prefix_length,
    gaussian_entropy,
    pessimistic_q,
    select_chunk,
)
from sb3_ua2c.config import normalize_discrete_dims

LOG_2PIE = math.log(2 * math.pi * math.e)


def test_gaussian_entropy_of_known_samples():
    # S=2 samples (0, 2) at one position: unbiased variance 2
    samples = th.tensor([0.0, 2.0]).reshape(2, 1, 1)
    h = gaussian_entropy(samples)
    assert h.shape == (1, 1)
    assert h.item() == pytest.approx(0.5 * (LOG_2PIE + math.log(2.0 + ENTROPY_EPS)), rel=1e-6)


def test_gaussian_entropy_zero_variance_is_finite():
    samples = th.full((8, 3, 1), 0.3)
    h = gaussian_entropy(samples)
    assert th.allclose(h, th.full((3, 1), 0.5 * (LOG_2PIE + math.log(ENTROPY_EPS))))
    # a single candidate has variance 0 by definition
    assert th.allclose(
        gaussian_entropy(th.ones(1, 2, 1)), th.full((2, 1), 0.5 * (LOG_2PIE + math.log(ENTROPY_EPS)))
    )


def test_categorize_uses_equal_width_bins():
    # 3 categories over [-1, 1]: thresholds at -1/3 and +1/3 (the traffic env's lane change)
    a = th.tensor([-1.0, -0.34, -0.33, 0.0, 0.33, 0.34, 1.0, 5.0, -5.0])
    assert categorize(a, 3).tolist() == [0, 0, 1, 1, 1, 2, 2, 2, 0]


def test_categorical_entropy_hand_computed():
    cats = th.tensor([0, 1, 2, 2]).reshape(4, 1)  # p = (1/4, 1/4, 1/2)
    assert categorical_entropy(cats, 3).item() == pytest.approx(1.5 * math.log(2.0))
    assert categorical_entropy(th.zeros(5, 1, dtype=th.long), 3).item() == pytest.approx(0.0)


def test_chunk_entropy_mixed_discrete_and_continuous():
    # S=4 candidates, k=2, action_dim=2: dim 0 continuous, dim 1 categorical with 3 values
    samples = th.zeros(4, 2, 2)
    samples[:, 0, 0] = th.tensor([0.0, 0.0, 2.0, 2.0])  # variance 4/3
    samples[:, 0, 1] = th.tensor([-0.9, 0.0, 0.9, 0.9])  # p = (1/4, 1/4, 1/2)
    samples[:, 1, 0] = 0.5  # zero variance
    samples[:, 1, 1] = 0.0  # one category
    h = chunk_entropy(samples, {1: 3}, discrete=True)
    expected0 = 0.5 * (LOG_2PIE + math.log(4 / 3 + ENTROPY_EPS)) + 1.5 * math.log(2.0)
    expected1 = 0.5 * (LOG_2PIE + math.log(ENTROPY_EPS))
    assert h.shape == (2,)
    assert h.tolist() == pytest.approx([expected0, expected1], rel=1e-5)
    # discrete=False: the continuous dim alone (the lane-change disagreement no longer counts)
    h_cont = chunk_entropy(samples, {1: 3}, discrete=False)
    assert h_cont.tolist() == pytest.approx([0.5 * (LOG_2PIE + math.log(4 / 3 + ENTROPY_EPS)), expected1], rel=1e-5)


def test_chunk_entropy_sums_continuous_dims_and_batches():
    samples = th.tensor([0.0, 2.0]).reshape(2, 1, 1).expand(2, 1, 3)  # 3 identical dims
    h = chunk_entropy(samples.unsqueeze(0).expand(5, 2, 1, 3), discrete=True)  # batch of 5
    assert h.shape == (5, 1)
    assert th.allclose(h, th.full((5, 1), 1.5 * (LOG_2PIE + math.log(2.0 + ENTROPY_EPS))))


@pytest.mark.parametrize(
    ("entropy", "threshold", "expected"),
    [
        ([0.9, 0.8, 0.7, 0.6], 0.5, 1),  # all above -> at least one action
        ([0.1, 0.2, 0.3, 0.4], 0.5, 4),  # all below -> the whole chunk
        ([0.1, 0.2, 0.9, 0.1], 0.5, 2),  # first crossing in the middle; later positions do not count
        ([0.5, 0.5, 0.6, 0.1], 0.5, 2),  # equality is reliable
        ([9.0, 9.0, 9.0, 9.0], math.inf, 4),  # delta = inf is fixed chunking
        ([0.1, math.nan, 0.1, 0.1], 0.5, 1),  # NaN is unreliable
    ],
)
def test_executable_prefix_length(entropy, threshold, expected):
    assert executable_prefix_length(th.tensor(entropy), threshold).item() == expected


@pytest.mark.parametrize(
    ("lane", "length", "expected"),
    [
        ([0.0, 0.0, 0.0, 0.9, 0.0], 1, 4),  # keep, keep, keep, change, keep: commit through u = 3
        ([0.0, 0.0, 0.0, 0.9, 0.0], 5, 5),  # the prefix never shrinks
        ([0.0, 0.2, -0.3, 0.0, 0.0], 1, 1),  # |a| < 1/3 stays "keep": no switch, L_t unchanged
        ([0.0, 0.0, 0.0, 0.0, -0.34], 2, 5),  # a change at the last position: the whole chunk
        ([0.9, 0.0, 0.0, 0.0, 0.0], 1, 2),  # a change now: the switch back at u = 1 is executed too
        ([0.9, 0.9, 0.9, 0.9, 0.9], 1, 1),  # one category throughout: no switch
        ([0.0, 0.9, -0.9, 0.0, 0.0], 3, 3),  # the first switch (u = 1) is already inside the prefix
    ],
)
def test_commit_through_switch_hand_computed(lane, length, expected):
    chunk = th.zeros(1, 5, 2)
    chunk[0, :, 0] = 0.7  # the continuous dim plays no part
    chunk[0, :, 1] = th.tensor(lane)
    assert commit_through_switch(th.tensor([length]), chunk, {1: 3}).tolist() == [expected]


def test_commit_through_switch_batched_several_dims_and_k1():
    chunks = th.zeros(3, 4, 3)
    chunks[0, 2, 1] = 1.0  # dim 1 switches at u = 2
    chunks[0, 1, 2] = -1.0  # dim 2 at u = 1: the later switch (dim 1) decides
    chunks[1, 3, 2] = -1.0  # dim 2 (two bins: 0 and 1 are one category) at u = 3
    got = commit_through_switch(th.tensor([1, 2, 2]), chunks, {1: 3, 2: 2})
    assert got.tolist() == [3, 4, 2]
    # no categorical dim, or k = 1: nothing to commit to
    assert commit_through_switch(th.tensor([1, 2, 2]), chunks, None).tolist() == [1, 2, 2]
    assert commit_through_switch(th.tensor([1]), th.ones(1, 1, 3), {1: 3}).tolist() == [1]


def test_executable_prefix_length_batched():
    h = th.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert executable_prefix_length(h, 0.5).tolist() == [2, 1, 3]


def test_chunk_target_full_window_eq4():
    r = th.tensor([[1.0, 1.0, 1.0]])
    # 1 + 0.5 + 0.25 + 0.5^3 * 8 = 2.75
    y = chunk_target(r, th.tensor([3]), th.tensor([1.0]), th.tensor([8.0]), gamma=0.5)
    assert y.item() == pytest.approx(2.75)


def test_chunk_target_terminal_and_truncation_inside_window():
    r = th.tensor([[1.0, 1.0, 7.0], [1.0, 1.0, 7.0], [2.0, 4.0, 8.0]])
    horizon = th.tensor([2, 2, 1])
    mask = th.tensor([0.0, 1.0, 1.0])
    v = th.tensor([8.0, 8.0, 10.0])
    y = chunk_target(r, horizon, mask, v, gamma=0.5)
    # terminal after 2 steps: 1 + 0.5, no bootstrap, reward after the end ignored
    # time-limit truncation after 2 steps: 1 + 0.5 + 0.25 * 8
    # adaptive prefix L_t = 1 (Eq. 8): 2 + 0.5 * 10
    assert y.tolist() == pytest.approx([1.5, 3.5, 7.0])
    assert discounted_chunk_return(r, horizon, 0.5).tolist() == pytest.approx([1.5, 1.5, 2.0])


def test_pessimistic_q_is_the_min_over_critics_and_its_gradient_picks_that_critic():
    # (n_critics=2, B=2, C=1), as the actor's value term of Eq. 2 sees it
    q = th.tensor([[[3.0], [-1.0]], [[2.0], [4.0]]], requires_grad=True)
    v = pessimistic_q(q)
    assert v.shape == (2, 1)
    assert v.tolist() == [[2.0], [-1.0]]
    v.sum().backward()
    # only the pessimistic critic of each sample receives the gradient
    assert q.grad.tolist() == [[[0.0], [1.0]], [[1.0], [0.0]]]
    # (n_critics=3, m=1, S=2), as the replanning of Eq. 7 ranks its candidates
    assert pessimistic_q(th.tensor([[[5.0, 0.0]], [[1.0, 9.0]], [[7.0, 2.0]]])).tolist() == [[1.0, 0.0]]


def test_bootstrap_value_is_max_over_candidates_of_min_over_critics():
    # (n_critics=2, B=2, Q=3)
    q = th.tensor(
        [
            [[1.0, 5.0, 3.0], [0.0, -2.0, 4.0]],
            [[2.0, 4.0, 6.0], [-1.0, 7.0, 1.0]],
        ]
    )
    # min_j: [[1, 4, 3], [-1, -2, 1]] -> max_q: [4, 1]
    assert bootstrap_value(q).tolist() == [4.0, 1.0]
    # the order matters: min_j max_q would give [min(5, 6), min(4, 7)] = [5, 4]
    assert q.max(dim=2).values.min(dim=0).values.tolist() == [5.0, 4.0]
    # one candidate (Q = 1) is the pessimistic value itself
    assert bootstrap_value(q[..., 1:2]).tolist() == [4.0, -2.0]


def test_chunk_critic_loss_hand_computed():
    q = th.tensor([[1.0, 2.0], [3.0, 4.0]])  # (n_critics, batch)
    y = th.tensor([1.0, 1.0])
    # critic 1: mean(0, 1) = 0.5 ; critic 2: mean(4, 9) = 6.5
    assert chunk_critic_loss(q, y).item() == pytest.approx(7.0)


def test_normalize_discrete_dims():
    assert normalize_discrete_dims(None, 2) == {}
    assert normalize_discrete_dims({1: [-1, 0, 1]}, 2) == {1: 3}
    with pytest.raises(ValueError, match="action index 2"):
        normalize_discrete_dims({2: [-1, 1]}, 2)
    with pytest.raises(ValueError, match="at least 2"):
        normalize_discrete_dims({0: [1]}, 2)
    with pytest.raises(ValueError, match="increasing"):
        normalize_discrete_dims({0: [1, 0]}, 2)
    with pytest.raises(ValueError, match="mapping"):
        normalize_discrete_dims([1], 2)


def test_select_chunk_best_and_elite_mean_hand_computed():
    # m = 1 history, S = 3 candidates, k = 2, action_dim = 2 (dim 1 categorical with 3 values)
    candidates = th.tensor(
        [[[[0.2, 1.0], [0.4, 1.0]], [[0.6, -1.0], [0.0, -1.0]], [[-0.8, 0.0], [-0.8, 0.0]]]]
    )
    values = th.tensor([[1.0, 3.0, 2.0]])  # best: candidate 1, then 2
    assert th.equal(select_chunk(candidates, values, 1), candidates[0, 1].unsqueeze(0))
    elite = select_chunk(candidates, values, n_elite=2, discrete_dims={1: 3})
    # continuous dim: mean of candidates 1 and 2 -> (0.6 - 0.8) / 2 = -0.1, (0.0 - 0.8) / 2 = -0.4;
    # categorical dim: the best candidate's lane change (-1), never an average
    assert th.allclose(elite, th.tensor([[[-0.1, -1.0], [-0.4, -1.0]]]))
    # without categorical dims every dim is averaged: (-1 + 0) / 2 = -0.5
    assert th.allclose(select_chunk(candidates, values, n_elite=2)[0, :, 1], th.tensor([-0.5, -0.5]))
    # n_elite = S: the mean of all candidates
    assert th.allclose(select_chunk(candidates, values, n_elite=3), candidates.mean(dim=1))


@pytest.mark.parametrize("n_elite", [0, 4])
def test_select_chunk_rejects_bad_elite_size(n_elite):
    with pytest.raises(ValueError, match="n_elite"):
        select_chunk(th.zeros(1, 3, 2, 1), th.zeros(1, 3), n_elite=n_elite)
