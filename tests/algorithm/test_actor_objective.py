"""How ``UA2C`` wires Eq. 2: the flow term ignores the padded tail of a window, the value term sees
x̂1 clipped to the action bounds."""

import pytest
import torch as th
from ua2c_helpers import FAST

from sb3_ua2c import UA2C
from sb3_ua2c.buffers import ChunkReplaySamples


def batch(tail: float, mask: th.Tensor | None) -> ChunkReplaySamples:
    """Two Pendulum-v1 samples (ℓ = 2, k = 3), chunk ``(0.5, -0.5, tail)``."""
    obs = th.arange(12, dtype=th.float32).reshape(2, 2, 3) / 10
    chunks = th.tensor([0.5, -0.5, tail]).reshape(1, 3, 1).repeat(2, 1, 1)
    zeros = th.zeros(2)
    return ChunkReplaySamples(obs, th.zeros(2, 2, 1), chunks, th.zeros(2, 3), zeros + 2, zeros, obs,
                              th.zeros(2, 2, 1), mask)


def flow_loss_of(model: UA2C, data: ChunkReplaySamples) -> float:
    th.manual_seed(7)  # the same x0 and tau every call
    return model._actor_loss(data)[1]["flow_loss"]


def test_flow_term_averages_the_valid_positions_only():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, history_len=2, **FAST)
    data = batch(0.0, th.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0]]))
    # the same draws as _actor_loss: x0 then tau
    th.manual_seed(7)
    x0 = th.randn(2, 3, 1)
    tau = th.rand(2)
    x1 = data.chunks
    with th.no_grad():
        cond = model.actor.condition(model.policy.flatten_history(data.observation_history, data.action_history))
        error = (model.actor((1 - tau[:, None, None]) * x0 + tau[:, None, None] * x1, tau, cond) - (x1 - x0)) ** 2
    # 5 valid entries: sample 0 without its padded last position, sample 1 whole
    by_hand = (error[0, :2].sum() + error[1].sum()).item() / 5
    assert flow_loss_of(model, data) == pytest.approx(by_hand, rel=1e-6)
    assert flow_loss_of(model, batch(0.0, None)) == pytest.approx(error.mean().item(), rel=1e-6)
    assert flow_loss_of(model, batch(0.0, th.ones(2, 3))) == flow_loss_of(model, batch(0.0, None))


def test_value_term_values_the_clipped_terminal_estimate():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, history_len=2, q_weight=10.0, **FAST)
    seen = []
    model.critic.register_forward_pre_hook(lambda _, args: seen.append(args[1].detach().clone()))
    with th.no_grad():  # a velocity of about 100 everywhere: x̂1 = x_tau + (1 - tau) v is far above 1
        model.actor.trunk[-1].bias.fill_(100.0)
    data = batch(0.0, None)
    grads = []
    for q_weight in (10.0, 0.0):
        model.q_weight = q_weight
        model.actor.zero_grad()
        th.manual_seed(7)
        model._actor_loss(data)[0].backward()
        grads.append([p.grad.clone() for p in model.actor.parameters()])
    # the critic saw x̂1 clipped to the upper bound 1 ...
    assert th.equal(seen[0], th.ones(2, 1, 3, 1))
    # ... and a plain clamp passes no gradient outside the bounds: the value term does not move the actor
    for with_q, without_q in zip(*grads, strict=True):
        assert th.equal(with_q, without_q)
