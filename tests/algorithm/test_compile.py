"""The ``torch_compile`` policy option: a constructor parameter that keeps the parameters and
checkpoints of eager mode, and compiled critics that compute the eager numbers to rounding."""

import pytest
import torch as th
from ua2c_helpers import tiny_policy

from sb3_ua2c import UA2C
from sb3_ua2c.policies import UA2CPolicy


def make_policy(**kwargs) -> UA2CPolicy:
    return tiny_policy(n_candidates=4, **kwargs)


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_torch_compile_rejects_non_bool(bad):
    with pytest.raises(ValueError, match="torch_compile must be a bool"):
        make_policy(torch_compile=bad)


@pytest.mark.slow
def test_torch_compile_keeps_parameters_checkpoints_and_constructor_parameters(tmp_path):
    th.manual_seed(0)
    eager = make_policy()
    th.manual_seed(0)
    compiled = make_policy(torch_compile=True)  # compiles lazily: nothing runs here
    eager_state, compiled_state = eager.state_dict(), compiled.state_dict()
    assert list(compiled_state) == list(eager_state)  # no ``_orig_mod.`` prefix
    assert all(th.equal(compiled_state[key], eager_state[key]) for key in eager_state)
    assert compiled._get_constructor_parameters()["torch_compile"] is True
    assert eager._get_constructor_parameters()["torch_compile"] is False
    compiled.save(str(tmp_path / "policy.pt"))
    loaded = UA2CPolicy.load(str(tmp_path / "policy.pt"))
    assert loaded.torch_compile is True
    # an eager checkpoint loads into a compiled policy and back
    compiled.load_state_dict(eager_state)
    eager.load_state_dict(compiled.state_dict())
    model = UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs={"torch_compile": True}, learning_starts=10)
    assert model.policy.torch_compile is True


@pytest.mark.slow
def test_compiled_critics_match_eager_to_rounding():
    th.manual_seed(0)
    eager = make_policy()
    compiled = make_policy(torch_compile=True)
    compiled.load_state_dict(eager.state_dict())
    obs_h = th.randn(5, 2 * 3)
    chunks = th.rand(5, 2, 3, 2) * 2.0 - 1.0  # (B, C, k, action_dim)
    outputs = []
    for policy in (eager, compiled):
        q = policy.critic(obs_h, chunks)  # (n, B, C)
        q.square().sum().backward()
        outputs.append((q.detach(), [p.grad.clone() for p in policy.critic.parameters()]))
    (q_eager, grads_eager), (q_compiled, grads_compiled) = outputs
    assert q_eager.shape == q_compiled.shape == (2, 5, 2)
    th.testing.assert_close(q_compiled, q_eager, rtol=1e-5, atol=1e-5)
    for grad_compiled, grad_eager in zip(grads_compiled, grads_eager, strict=True):
        th.testing.assert_close(grad_compiled, grad_eager, rtol=1e-4, atol=1e-5)
