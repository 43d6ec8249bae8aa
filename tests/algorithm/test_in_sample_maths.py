"""The in-sample maths (:mod:`sb3_ua2c.in_sample_maths`) against hand-computed values."""

import math

import pytest
import torch as th

from sb3_ua2c.in_sample_maths import advantage_weights, expectile_loss, softmax_candidate


def test_expectile_loss_hand_computed():
    # u = q - v = [1, -2]: weights [tau, 1 - tau] = [0.7, 0.3]; loss = (0.7 * 1 + 0.3 * 4) / 2 = 0.95
    q, v = th.tensor([1.0, 0.0]), th.tensor([0.0, 2.0])
    assert expectile_loss(q, v, 0.7).item() == pytest.approx(0.95)
    # tau = 0.5 is half the mean squared error: (1 + 4) / 2 * 0.5 = 1.25
    assert expectile_loss(q, v, 0.5).item() == pytest.approx(1.25)


def test_expectile_loss_trains_v_only():
    q = th.tensor([1.0, 3.0], requires_grad=True)
    v = th.tensor([0.0, 0.0], requires_grad=True)
    expectile_loss(q, v, 0.9).backward()
    assert q.grad is None
    # d/dv of tau u^2 / B = -2 tau u / B: -2 * 0.9 * [1, 3] / 2
    assert v.grad.tolist() == pytest.approx([-0.9, -2.7])


def test_expectile_minimiser_is_the_expectile():
    # the v minimising the loss over samples {0, 1} with tau = 0.8 solves 0.8 (1 - v) = 0.2 v: v = 0.8
    v = th.zeros(1, requires_grad=True)
    opt = th.optim.SGD([v], lr=0.5)
    for _ in range(200):
        opt.zero_grad()
        expectile_loss(th.tensor([0.0, 1.0]), v.expand(2), 0.8).backward()
        opt.step()
    assert v.item() == pytest.approx(0.8, abs=1e-4)


def test_advantage_weights_hand_computed():
    q, v = th.tensor([1.0, 0.0, 5.0, -1.0]), th.zeros(4)
    w = advantage_weights(q, v, temperature=2.0, max_weight=100.0)
    assert w.tolist() == pytest.approx([math.exp(2.0), 1.0, 100.0, math.exp(-2.0)])
    assert advantage_weights(q, v, temperature=0.0, max_weight=100.0).tolist() == [1.0] * 4


def test_softmax_candidate_frequencies():
    # values [0, ln 3] at T = 1: probabilities [1/4, 3/4]
    values = th.tensor([[0.0, math.log(3.0)]]).expand(20_000, 2)
    picks = softmax_candidate(values, 1.0, th.Generator().manual_seed(0))
    assert picks.shape == (20_000,)
    assert picks.float().mean().item() == pytest.approx(0.75, abs=0.01)


def test_softmax_candidate_limits():
    values = th.tensor([[1.0, 5.0, 2.0], [1e4, 0.0, -1e4]])
    assert softmax_candidate(values, 1e-3).tolist() == [1, 0]  # T -> 0: the best, no overflow
    uniform = softmax_candidate(th.zeros(30_000, 3), 1.0, th.Generator().manual_seed(1))
    assert th.bincount(uniform, minlength=3).div(30_000).tolist() == pytest.approx([1 / 3] * 3, abs=0.01)
