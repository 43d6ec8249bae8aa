"""The options beyond the paper in training: the in-sample chunk value (``critic_target="in_sample"``),
advantage-weighted extraction (``actor_extraction="awr"``) and softmax exploration
(``exploration="softmax"``): their targets and losses against hand-computed numbers, where they act
(learn's rollouts, not ``predict``), checkpoints with the value network, seeding, switching after
Phase 1, bad values, and the defaults left bit for bit as they were."""

import math
import platform
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import FAST, TINY, rollout_actions, state_hash, tiny_policy

from sb3_ua2c import UA2C
from sb3_ua2c.buffers import ChunkReplaySamples
from sb3_ua2c.chunking import chunk_critic_loss, select_chunk
from sb3_ua2c.exploration import SoftmaxExploration
from sb3_ua2c.extraction import AdvantageWeightedExtraction
from sb3_ua2c.flow import interpolate
from sb3_ua2c.policies import UA2CPolicy
from sb3_ua2c.targets import ChunkValue, InSampleTarget, TargetInputs

ALL = dict(critic_target="in_sample", actor_extraction="awr", exploration="softmax")
#: the state-dict hashes of ``trained(exploration="plan")`` (the defaults until 2026-12-07), recorded before
#: the options existed (torch 2.13.0+cpu, x86_64): one per CPU kernel set seen so far (torch picks AVX2 or AVX-512
#: kernels by the CPU, and they round differently); float results may differ on other builds, where
#: the check is skipped
DEFAULTS_HASH = ("2.13.0+cpu", "x86_64", {"38016077f199f609fea01723e8742ac4a62870a15e9b8b980cefdad45dae2172",
                                          "d646c24424f46962f2033c2ba2ec59ddad9713b8ed982e683a6eba58ae72982b"})


def trained(steps: int = 150, **kwargs) -> UA2C:
    args = {**FAST, "chunk_size": 3, "history_len": 2, "seed": 0, **kwargs}
    return UA2C("MlpPolicy", "Pendulum-v1", **args).learn(steps)


def set_value_constant(value: ChunkValue, constant: float) -> None:
    """``V(h) = constant`` for every history: every weight 0 and the read-out's bias ``constant``."""
    with th.no_grad():
        for p in value.parameters():
            p.zero_()
        value.net[-1].bias.fill_(constant)


class FixedQ(nn.Module):
    """Critics whose values are given: ``(B, ·), (B, 1, k, A) -> (n, B, 1)``."""

    def __init__(self, q: th.Tensor) -> None:
        super().__init__()
        self.q = q  # (n, B)

    def forward(self, obs_history: th.Tensor, chunks: th.Tensor) -> th.Tensor:
        return self.q.unsqueeze(-1)  # (n, B) -> (n, B, 1)


def pendulum_batch(model: UA2C, rewards, horizons, bootstrap) -> ChunkReplaySamples:
    """A hand-built batch of Pendulum-v1 histories (ℓ = 2, k = 3) with the given rewards, ``L`` and ``m``."""
    b = len(horizons)
    gen = th.Generator().manual_seed(0)
    obs = th.rand((b, 2, 3), generator=gen)
    act = th.rand((b, 2, 1), generator=gen) * 2 - 1
    chunks = th.rand((b, 3, 1), generator=gen) * 2 - 1
    return ChunkReplaySamples(obs, act, chunks, th.tensor(rewards), th.tensor(horizons, dtype=th.long),
                              th.tensor(bootstrap), obs.flip(0), act.flip(0))


# ------------------------------------------------------------------------------ the in-sample target
def test_in_sample_target_is_the_hand_computed_chunk_target(monkeypatch):
    model = UA2C("MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, gamma=0.5, learning_rate=0.0,
                 critic_target="in_sample", **FAST)
    set_value_constant(model.policy.value, 2.0)
    # rewards [1, 2, 4]; L = 3, 2, 1; m = 1, 1, 0; gamma = 0.5, V(h') = 2:
    # 1 + 1 + 1 + 0.125 * 2 = 3.25;  1 + 1 + 0.25 * 2 = 2.5;  1 (terminated: no bootstrap)
    data = pendulum_batch(model, [[1.0, 2.0, 4.0]] * 3, [3, 2, 1], [1.0, 1.0, 0.0])
    expected = th.tensor([3.25, 2.5, 1.0])
    obs_flat = data.observation_history.flatten(1)
    with th.no_grad():
        q = model.critic(obs_flat, data.chunks.unsqueeze(1)).squeeze(2)  # (n, B)
    # no actor candidate is sampled for the target (nor by the AWR objective)
    monkeypatch.setattr(model.policy, "sample_chunks", lambda *a, **k: pytest.fail("candidates sampled"))
    model._n_updates = 1  # no periodic diagnostics at this update
    info = model._gradient_step(data)
    assert model._next_values(data.next_observation_history, data.next_action_history).tolist() == [2.0] * 3
    assert info["critic_loss"] == pytest.approx(chunk_critic_loss(q, expected).item(), rel=1e-6)
    assert info["v_mean"] == pytest.approx(2.0)
    assert set(info) >= {"value_loss", "v_mean", "critic_loss", "actor_loss"}


def test_expectile_update_moves_v_to_the_expectile():
    # one history, two data chunks with min_j Q̄_j = 0 and 1 (twin critics 0/2 and 1/3): tau = 0.8 -> V = 0.8
    value = ChunkValue(2, nn.ReLU, [4], layer_norm=False)
    set_value_constant(value, 0.0)
    policy = SimpleNamespace(critic_target=FixedQ(th.tensor([[0.0, 1.0], [2.0, 3.0]])), value=value)
    inputs = TargetInputs(policy, 1, 1)  # type: ignore[arg-type]
    data = SimpleNamespace(observation_history=th.ones(2, 1, 2), chunks=th.zeros(2, 3, 1))
    target = InSampleTarget(expectile=0.8, net_arch=[4], layer_norm=False)
    optimizer = th.optim.Adam(value.parameters(), lr=0.02)
    loss, info = target.value_loss(inputs, data)
    # V = 0: u = [0, 1], loss = (0.8 * 0 + 0.8 * 1) / 2
    assert (loss.item(), info["v_mean"]) == (pytest.approx(0.4), 0.0)
    for _ in range(600):
        loss, _ = target.value_loss(inputs, data)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert value(th.ones(1, 2)).item() == pytest.approx(0.8, abs=1e-3)
    assert target.next_value(inputs, th.ones(3, 1, 2), th.zeros(3, 1, 1)).tolist() == pytest.approx([0.8] * 3, abs=1e-3)


# ------------------------------------------------------------------------------ advantage-weighted extraction
def test_awr_loss_is_the_hand_weighted_flow_loss():
    policy = tiny_policy(value_arch=dict(net_arch=[8], layer_norm=True))
    set_value_constant(policy.value, 0.5)
    # min over the twins: [1, -1, 2]; A = Q - V = [0.5, -1.5, 1.5]; beta = 2, w_max = 10
    policy.critic_target = FixedQ(th.tensor([[1.0, 0.0, 2.0], [1.5, -1.0, 2.5]]))
    weights = [math.exp(1.0), math.exp(-3.0), 10.0]  # exp(3) = 20.1 is clipped to 10
    gen = th.Generator().manual_seed(0)
    obs, act, x1 = th.randn(3, 2, 3, generator=gen), th.randn(3, 2, 2, generator=gen), th.rand(3, 3, 2, generator=gen)
    mask = th.tensor([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 0.0]])  # the last position of row 3 is padding
    data = SimpleNamespace(observation_history=obs, action_history=act, chunks=x1, chunk_mask=mask)
    model_weights = SimpleNamespace(smooth_weight=0.0, past_action_dropout=0.0)
    out = AdvantageWeightedExtraction(temperature=2.0, max_weight=10.0).objective(
        policy, data, model_weights, th.Generator().manual_seed(1))
    # the same noise and times by hand: x0 ~ N(0, 1), tau ~ U(0, 1) from the generator, in that order
    gen = th.Generator().manual_seed(1)
    x0, tau = th.randn(x1.shape, generator=gen), th.rand(3, generator=gen)
    with th.no_grad():
        velocity = policy.actor(interpolate(x0, x1, tau), tau, policy.condition(obs, act))
    error = (velocity - (x1 - x0)).pow(2) * mask.unsqueeze(-1)  # (B, k, A)
    by_hand = sum(w * error[b].sum().item() for b, w in enumerate(weights)) / (8 * 2)  # 8 valid positions x 2 dims
    assert out.loss.item() == pytest.approx(by_hand, rel=1e-5)
    assert out.info["awr_weight_mean"] == pytest.approx(sum(weights) / 3, rel=1e-6)
    assert out.info["awr_weight_max"] == pytest.approx(10.0)
    # beta = 0: plain (masked) flow matching, every weight 1
    plain = AdvantageWeightedExtraction(temperature=0.0).objective(policy, data, model_weights,
                                                                   th.Generator().manual_seed(1))
    assert plain.loss.item() == pytest.approx(error.sum().item() / 16, rel=1e-5)
    assert plain.info["awr_weight_mean"] == 1.0


# ------------------------------------------------------------------------------ softmax exploration
def test_softmax_selection_draws_candidates_not_the_elite_mean():
    candidates = th.tensor([[[[0.0]], [[1.0]], [[-1.0]]]])  # (1, S=3, k=1, A=1)
    values = th.tensor([[0.0, 5.0, 1.0]])
    # T -> 0: the best candidate itself; the elite mean of 2 averages the best two, (1 + -1) / 2
    assert SoftmaxExploration(1e-4).select(candidates, values[None], 2, {}).tolist() == [[[1.0]]]
    assert select_chunk(candidates, values, 2, {}).tolist() == [[[0.0]]]
    th.manual_seed(0)
    picks = [SoftmaxExploration(100.0).select(candidates, values[None], 2, {}).item() for _ in range(300)]
    assert set(picks) == {0.0, 1.0, -1.0}  # T large: nearly uniform over the candidates


def test_softmax_acts_in_learn_only(tmp_path, monkeypatch):
    calls = []
    original = SoftmaxExploration.select
    monkeypatch.setattr(SoftmaxExploration, "select", lambda self, *a: calls.append(1) or original(self, *a))
    model = trained(120, exploration="softmax")
    assert len(calls) > 0  # the rollouts after the warm-up drew their chunks
    n_calls = len(calls)
    actions = rollout_actions(model)
    assert len(calls) == n_calls  # predict keeps the elite mean
    model.save(tmp_path / "model")
    as_plan = UA2C.load(tmp_path / "model", exploration="plan")
    assert as_plan.exploration == "plan" and as_plan.exploration_kwargs == {}
    np.testing.assert_array_equal(rollout_actions(as_plan), actions)
    # and the other way round: a checkpoint of "plan" acts the same with "softmax"
    assert UA2C.load(tmp_path / "model").exploration_kwargs == {"temperature": 1.0}
    as_plan.save(tmp_path / "plan")
    np.testing.assert_array_equal(rollout_actions(UA2C.load(tmp_path / "plan", exploration="softmax")), actions)


# ------------------------------------------------------------------------------ checkpoints, seeds, switching
def test_save_load_with_the_value_network(tmp_path):
    model = trained(120, **ALL, critic_target_kwargs=dict(expectile=0.9, net_arch=[16]))
    assert [k for k in model.policy.state_dict() if k.startswith("value.")] == [
        "value.net.0.weight", "value.net.0.bias", "value.net.1.weight", "value.net.1.bias",
        "value.net.3.weight", "value.net.3.bias"]
    actions = rollout_actions(model)
    model.save(tmp_path / "model")
    loaded = UA2C.load(tmp_path / "model")
    assert (loaded.critic_target_name, loaded.actor_extraction, loaded.exploration) == tuple(ALL.values())
    assert loaded.critic_target_kwargs == {"expectile": 0.9, "net_arch": [16], "layer_norm": True}
    for key, value in model.policy.state_dict().items():
        assert th.equal(value, loaded.policy.state_dict()[key]), key
    assert loaded.policy.value.optimizer.state_dict()["state"].keys() == model.policy.value.optimizer.state_dict()[
        "state"].keys() != set()
    np.testing.assert_array_equal(rollout_actions(loaded), actions)
    model.policy.save(tmp_path / "policy")
    policy = UA2CPolicy.load(tmp_path / "policy")
    assert th.equal(policy.value.net[0].weight, model.policy.value.net[0].weight)
    np.testing.assert_array_equal(rollout_actions(policy), actions)


def test_seeded_runs_with_every_option_are_bit_identical():
    first, second = trained(**ALL), trained(**ALL)
    assert state_hash(first) == state_hash(second)
    assert state_hash(first) != state_hash(trained(critic_target="in_sample"))


def test_switching_the_target_after_phase_one(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, seed=0, **FAST)
    rng = np.random.default_rng(0)
    end = np.zeros(40, dtype=bool)
    end[-1] = True
    model.add_offline_episodes([dict(observations=rng.uniform(-1, 1, (41, 3)).astype(np.float32),
                                     actions=rng.uniform(-2, 2, (40, 1)).astype(np.float32),
                                     rewards=rng.normal(size=40), terminations=np.zeros(40, dtype=bool),
                                     truncations=end)] * 2)
    model.pretrain(20)  # Phase 1 with the paper's bootstrap
    assert model.policy.value is None
    model.save(tmp_path / "phase1")
    model.set_critic_target("in_sample", {"expectile": 0.8})
    model.set_actor_extraction("awr")
    assert model.policy.value is not None and model.critic_target_kwargs["expectile"] == 0.8
    model.learn(80)  # Phase 2 with the in-sample value
    assert model.logger.name_to_value["train/value_loss"] > 0.0
    assert "train/awr_weight_max" in model.logger.name_to_value
    # the Phase-1 checkpoint (no V) loads into the in-sample options and learns on
    loaded = UA2C.load(tmp_path / "phase1", env=gym.make("Pendulum-v1"), critic_target="in_sample", actor_extraction="awr")
    assert loaded.policy.value is not None and loaded.critic_target_name == "in_sample"
    assert UA2C.load(tmp_path / "phase1").policy.value is None  # and without them, as before
    loaded.learn(60)
    # back to the candidates: awr needs V, so the extraction goes first; then V is dropped
    with pytest.raises(ValueError, match="actor_extraction"):
        model.set_critic_target("candidates")
    model.set_actor_extraction("value_term")
    model.set_critic_target("candidates")
    assert model.policy.value is None and "value.net.0.weight" not in model.policy.state_dict()


# ------------------------------------------------------------------------------ bad values
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(critic_target="in_sample", critic_target_kwargs=dict(expectile=1.5)), r"critic_target_kwargs\['expectile'\]"),
        (dict(critic_target="in_sample", critic_target_kwargs=dict(expectile=0.0)), r"critic_target_kwargs\['expectile'\]"),
        (dict(critic_target="in_sample", critic_target_kwargs=dict(net_arch=[])), r"critic_target_kwargs\['net_arch'\]"),
        (dict(critic_target="in_sample", critic_target_kwargs=dict(tau=0.7)), "critic_target_kwargs key 'tau'"),
        (dict(critic_target="candidates", critic_target_kwargs=dict(expectile=0.7)), "critic_target_kwargs key"),
        (dict(critic_target="iql"), "critic_target must be one of"),
        (dict(actor_extraction="bc"), "actor_extraction must be one of"),
        (dict(exploration="epsilon"), "exploration must be one of"),
        (dict(actor_extraction="awr"), "actor_extraction='awr'"),
        (dict(**ALL, actor_extraction_kwargs=dict(max_weight=0.0)), r"actor_extraction_kwargs\['max_weight'\]"),
        (dict(**ALL, actor_extraction_kwargs=dict(temperature=-1.0)), r"actor_extraction_kwargs\['temperature'\]"),
        (dict(exploration="softmax", exploration_kwargs=dict(temperature=0.0)), r"exploration_kwargs\['temperature'\]"),
        (dict(exploration="softmax", exploration_kwargs=[1.0]), "exploration_kwargs must be a dict"),
        (dict(**ALL, policy_kwargs=dict(actor_type="one_step")), "actor_extraction='awr' trains actor_type"),
        (dict(policy_kwargs=dict(value_arch=dict(net_arch=[8], layer_norm=True))), "value_arch"),
    ],
)
def test_bad_values_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        UA2C("MlpPolicy", "Pendulum-v1", **{**FAST, **kwargs})


def test_a_bad_setter_call_changes_nothing():
    model = UA2C("MlpPolicy", "Pendulum-v1", **FAST)
    with pytest.raises(ValueError, match=r"critic_target_kwargs\['expectile'\]"):
        model.set_critic_target("in_sample", {"expectile": 1.5})
    assert model.critic_target_name == "candidates" and model.policy.value is None
    with pytest.raises(ValueError, match="actor_extraction"):
        model.set_actor_extraction("awr")


# ------------------------------------------------------------------------------ the defaults, bit for bit
def test_the_defaults_train_as_before():
    plain = trained()
    explicit = trained(critic_target="candidates", actor_extraction="value_term", exploration="softmax")
    assert state_hash(plain) == state_hash(explicit)
    assert plain.policy.value is None and not any(k.startswith("value.") for k in plain.policy.state_dict())
    # the defaults until 2026-12-07 (rollouts acting as predict) train as before the options existed
    as_plan = trained(exploration="plan")
    assert state_hash(as_plan) != state_hash(plain)  # the draw changes what the rollouts execute
    torch_version, machine, recorded = DEFAULTS_HASH
    if (th.__version__, platform.machine()) != (torch_version, machine):
        pytest.skip(f"the recorded hash is of torch {torch_version} on {machine}")
    assert state_hash(as_plan) in recorded


def test_policy_kwargs_in_the_tiny_settings_are_untouched():
    # the shared settings must not carry an option (they would change every other test)
    assert "value_arch" not in TINY and not set(FAST) & set(ALL)
