"""Flow-matching maths (Eq. 2) against hand-computed values."""

import math

import pytest
import torch as th
from torch import nn

from sb3_ua2c.actors import VelocityField
from sb3_ua2c.flow import (
    actor_loss,
    chunk_roughness,
    estimate_terminal,
    euler_sample,
    euler_times,
    flow_matching_loss,
    interpolate,
    target_velocity,
)


def chunk(*values: float) -> th.Tensor:
    """One chunk of k=len(values) one-dimensional actions: shape (1, k, 1)."""
    return th.tensor(values, dtype=th.float32).reshape(1, -1, 1)


def test_interpolate_hand_computed():
    x0, x1 = chunk(0.0, 2.0), chunk(1.0, 4.0)
    x_tau = interpolate(x0, x1, th.tensor([0.25]))
    # (1 - 0.25) * 0 + 0.25 * 1 = 0.25 ; 0.75 * 2 + 0.25 * 4 = 2.5
    assert th.allclose(x_tau, chunk(0.25, 2.5))
    assert th.equal(interpolate(x0, x1, th.tensor([0.0])), x0)
    assert th.equal(interpolate(x0, x1, th.tensor([1.0])), x1)


def test_interpolate_per_sample_tau():
    x0 = th.zeros(2, 1, 1)
    x1 = th.ones(2, 1, 1)
    out = interpolate(x0, x1, th.tensor([0.1, 0.7]))
    assert th.allclose(out.flatten(), th.tensor([0.1, 0.7]))


def test_tau_shape_mismatch_raises():
    with pytest.raises(ValueError, match="tau"):
        interpolate(th.zeros(2, 3, 1), th.zeros(2, 3, 1), th.zeros(3))


def test_terminal_estimate_hand_computed():
    # x̂1 = 0.25 + (1 - 0.25) * 2 = 1.75
    out = estimate_terminal(chunk(0.25), th.tensor([0.25]), chunk(2.0))
    assert th.allclose(out, chunk(1.75))


def test_terminal_estimate_exact_for_the_straight_path():
    x0, x1 = chunk(-1.0, 0.5, 3.0), chunk(2.0, 0.0, -1.0)
    tau = th.tensor([0.3])
    x_hat = estimate_terminal(interpolate(x0, x1, tau), tau, target_velocity(x0, x1))
    assert th.allclose(x_hat, x1, atol=1e-6)


def test_flow_matching_loss_hand_computed():
    # target velocity (1, 1); prediction (1, 2): squared errors (0, 1), mean 0.5
    loss = flow_matching_loss(chunk(1.0, 2.0), chunk(0.0, 0.0), chunk(1.0, 1.0))
    assert loss.item() == pytest.approx(0.5)


def test_euler_constant_and_linear_fields():
    x0 = chunk(1.0, -2.0)
    # constant velocity 3: any number of steps reaches x0 + 3
    assert th.allclose(euler_sample(lambda x, t: th.full_like(x, 3.0), x0, 4), x0 + 3.0)
    # v = -x with 2 steps: x * (1 - 1/2) * (1 - 1/2)
    assert th.allclose(euler_sample(lambda x, t: -x, x0, 2), 0.25 * x0)
    # v = tau with 2 steps (tau = 0, 0.5): x0 + 0.5 * 0 + 0.5 * 0.5
    assert th.allclose(euler_sample(lambda x, t: th.ones_like(x) * t, x0, 2), x0 + 0.25)


def test_euler_rejects_zero_steps():
    with pytest.raises(ValueError, match="n_steps"):
        euler_sample(lambda x, t: x, chunk(0.0), 0)


def test_euler_times_and_step_inputs():
    assert th.equal(euler_times(4), th.tensor([0.0, 0.25, 0.5, 0.75]))
    # step inputs replace tau_i: v = row i of (10, 20) with 2 steps: x0 + 0.5 * 10 + 0.5 * 20
    x0 = chunk(1.0, -2.0)
    rows = th.tensor([10.0, 20.0])
    assert th.allclose(euler_sample(lambda x, r: th.ones_like(x) * r, x0, 2, rows), x0 + 15.0)
    with pytest.raises(ValueError, match="step_inputs must have 3 rows"):
        euler_sample(lambda x, r: x, x0, 3, rows)


def test_velocity_field_sample_is_euler_over_forward():
    """The precomputed history/time terms of ``VelocityField.sample`` give exactly the Euler
    integration of ``forward`` (same float operations in the same order)."""
    th.manual_seed(0)
    field = VelocityField(history_dim=6, chunk_size=3, action_dim=2, net_arch=[16, 16], activation_fn=nn.SiLU)
    cond = field.condition(th.randn(4, 6))  # (B=4, hidden)
    x0 = th.randn(4, 5, 3, 2)  # (B, S=5, k, A)
    with th.no_grad():
        reference = euler_sample(lambda x, tau: field(x, tau, cond), x0, 7)
        assert th.equal(field.integrate(x0, cond, 7), reference)
        # the velocity of one chunk does not depend on the other candidates of its history
        assert th.allclose(field.integrate(x0[:, :1], cond, 7), reference[:, :1], atol=1e-6)


def test_actor_loss_hand_computed():
    v, x0, x1 = chunk(1.0, 2.0), chunk(0.0, 0.0), chunk(1.0, 1.0)
    q = th.tensor([-2.0, -4.0])
    loss, info = actor_loss(v, x0, x1, q, q_weight=0.5, smooth_weight=0.0, normalize_q=True)
    # flow 0.5 ; q_scale = mean|q| = 3 ; q_term = -mean(q) / 3 = 1 ; loss = 0.5 + 0.5 * 1
    assert info["flow_loss"] == pytest.approx(0.5)
    assert info["q_scale"] == pytest.approx(3.0)
    assert info["q_term"] == pytest.approx(1.0)
    assert loss.item() == pytest.approx(1.0)


def test_chunk_roughness_hand_computed():
    # steps inside the chunk 0 -> 1 -> 3: changes 1 and 2, mean of squares (1 + 4) / 2 = 2.5
    assert chunk_roughness(chunk(0.0, 1.0, 3.0), [0]).item() == pytest.approx(2.5)
    # two dims, only dim 0 counts (dim 1 is categorical): changes 0.5 and -0.5 -> 0.25
    two = th.tensor([[[0.0, -1.0], [0.5, 1.0], [0.0, -1.0]]])  # (B=1, k=3, A=2)
    assert chunk_roughness(two, [0]).item() == pytest.approx(0.25)
    # both dims: (0.25 + 4 + 0.25 + 4) / 4
    assert chunk_roughness(two, [0, 1]).item() == pytest.approx(2.125)
    # a one-step chunk has no step inside it, and no dims means nothing counts
    assert chunk_roughness(chunk(5.0), [0]).item() == 0.0
    assert chunk_roughness(two, []).item() == 0.0


def test_actor_loss_adds_the_smoothness_term():
    v, x0, x1 = chunk(1.0, 2.0), chunk(0.0, 0.0), chunk(1.0, 1.0)
    q = th.tensor([-2.0, -4.0])
    x_hat = chunk(0.0, 0.5).requires_grad_(True)
    loss, info = actor_loss(v, x0, x1, q, 0.5, 4.0, True, chunk_roughness(x_hat, [0]))
    # 1.0 of the hand-computed Eq. 2 above + 4 * 0.5^2
    assert info["roughness"] == pytest.approx(0.25)
    assert loss.item() == pytest.approx(2.0)
    loss.backward()
    # d/dx of 4 * (x1 - x0)^2 = 8 * (x1 - x0) * (+-1) = -+4
    assert th.allclose(x_hat.grad, chunk(-4.0, 4.0))
    # mu = 0 is Eq. 2 exactly, with or without a roughness
    plain, plain_info = actor_loss(v, x0, x1, q, 0.5, 0.0, True)
    assert plain.item() == pytest.approx(1.0) and "roughness" not in plain_info
    with pytest.raises(ValueError, match="smooth_weight"):
        actor_loss(v, x0, x1, q, 0.5, 1.0, True, None)


def test_actor_loss_value_gradient_only_through_q():
    v = chunk(0.0).requires_grad_(True)
    q = th.tensor([2.0, 6.0], requires_grad=True)
    loss, _ = actor_loss(v, chunk(0.0), chunk(0.0), q, q_weight=2.0, smooth_weight=0.0, normalize_q=True)
    loss.backward()
    # d/dq_i of -2 * mean(q) / 4 = -2 / (2 * 4) = -0.25 (the scale is detached)
    assert th.allclose(q.grad, th.tensor([-0.25, -0.25]))
    assert math.isclose(v.grad.item(), 0.0)


def test_flow_matching_loss_masks_the_padding():
    # sample 0: errors (0, 1, 16) with the last position padding; sample 1: errors (4, 0, 0), all valid
    v = th.tensor([[1.0, 2.0, 5.0], [3.0, 1.0, 1.0]]).unsqueeze(-1)  # (B=2, k=3, A=1)
    x0, x1 = th.zeros_like(v), th.ones_like(v)
    mask = th.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
    # (0 + 1 + 4 + 0 + 0) / 5 valid entries; unmasked (0 + 1 + 16 + 4 + 0 + 0) / 6
    assert flow_matching_loss(v, x0, x1, mask).item() == pytest.approx(1.0)
    assert flow_matching_loss(v, x0, x1).item() == pytest.approx(3.5)
    assert flow_matching_loss(v, x0, x1, th.ones(2, 3)).item() == pytest.approx(3.5)
    # two action dims: the mask covers both dims of a position: errors 1 and 9 at u = 0, 100 padded
    v2 = th.tensor([[[1.0, 3.0], [10.0, 10.0]]])  # (1, k=2, A=2), targets 0
    assert flow_matching_loss(v2, th.zeros_like(v2), th.zeros_like(v2), th.tensor([[1.0, 0.0]])).item() == 5.0
    # no valid position: 0, not nan
    assert flow_matching_loss(v, x0, x1, th.zeros(2, 3)).item() == 0.0


def test_actor_loss_mask_leaves_the_padding_without_gradient():
    v = chunk(1.0, 2.0, 5.0).requires_grad_(True)
    loss, info = actor_loss(v, chunk(0.0, 0.0, 0.0), chunk(1.0, 1.0, 1.0), th.tensor([-2.0, -4.0]), 0.5,
                            0.0, True, mask=th.tensor([[1.0, 1.0, 0.0]]))
    # flow (0 + 1) / 2 = 0.5 ; the value term as in test_actor_loss_hand_computed: 0.5 * 1
    assert info["flow_loss"] == pytest.approx(0.5)
    assert loss.item() == pytest.approx(1.0)
    loss.backward()
    # d/dv_u of (v_u - 1)^2 / 2 = v_u - 1 on the valid positions, 0 on the padding
    assert th.allclose(v.grad, chunk(0.0, 1.0, 0.0))
