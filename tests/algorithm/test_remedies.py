"""The remedies as switches: history dropout and an actor without past actions (copycat), the value term
without normalisation, QC-FQL's one-step policy, and the paper preset. Defaults leave training as it was."""

import inspect
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.noise import ActionNoise
from ua2c_helpers import FAST, TINY, model_objective, rollout_actions, state_hash, tiny_policy

from sb3_ua2c import UA2C, UA2CPolicy
from sb3_ua2c.diagnostics import METRICS, diagnose, plan_sensitivity, policy_gap, value_term_strength
from sb3_ua2c.flow import actor_loss, distillation_loss, drop_past_actions, one_step_actor_loss, value_term
from sb3_ua2c.policies import DEFAULT_NET_ARCH
from sb3_ua2c.presets import PAPER, preset

REPO = Path(__file__).resolve().parents[2]
#: the new arguments at their defaults
NEW_MODEL_DEFAULTS = dict(past_action_dropout=0.0, normalize_q=True, distill_weight=100.0)
NEW_POLICY_DEFAULTS = dict(actor_type="flow", actor_past_actions=True)
ONE_STEP = dict(actor_type="one_step")


def chunks(*rows) -> th.Tensor:
    """Chunks of one-dimensional actions: ``len(rows)`` chunks of ``k = len(row)`` -> ``(B, k, 1)``."""
    return th.tensor(rows, dtype=th.float32).unsqueeze(-1)


def trained(steps: int = 150, **kwargs) -> UA2C:
    policy_kwargs = {**TINY, **kwargs.pop("policy_kwargs", {})}
    args = {**FAST, "chunk_size": 3, "history_len": 2, "seed": 0, **kwargs, "policy_kwargs": policy_kwargs}
    return UA2C("MlpPolicy", "Pendulum-v1", **args).learn(steps)


# ------------------------------------------------------------------------------ the losses, by hand
def test_distillation_loss_hand_computed():
    mu = chunks([0.5, 1.0], [-1.0, 0.0])  # 2 chunks of k=2, A=1
    flow = chunks([0.0, 0.5], [-0.5, 1.0])
    # differences 0.5, 0.5, -0.5, -1 -> squares 0.25, 0.25, 0.25, 1 -> mean 1.75 / 4
    assert distillation_loss(mu, flow).item() == pytest.approx(0.4375)
    mu.requires_grad_(True)
    flow.requires_grad_(True)
    distillation_loss(mu, flow).backward()
    # d/dmu = 2 (mu - flow) / 4; the flow's sample is a target: no gradient
    assert th.allclose(mu.grad, chunks([0.25, 0.25], [-0.25, -0.5]))
    assert flow.grad is None


@pytest.mark.parametrize(("normalize_q", "q_term", "loss"), [(True, 1 / 3, 2.075), (False, 1.0, 4.075)])
def test_one_step_actor_loss_hand_computed(normalize_q, q_term, loss):
    mu, flow = chunks([0.5, 1.0], [-1.0, 0.0]), chunks([0.0, 0.5], [-0.5, 1.0])
    q = th.tensor([2.0, -4.0])  # mean -1, mean |Q| = 3
    # 0.2 (flow) + alpha 2 * 0.4375 (distillation) + lambda 3 * q_term
    total, info = one_step_actor_loss(th.tensor(0.2), mu, flow, q, 3.0, 2.0, normalize_q)
    assert total.item() == pytest.approx(loss)
    assert info == pytest.approx({"flow_loss": 0.2, "distill_loss": 0.4375, "q_term": q_term, "q_scale": 3.0})


def test_value_term_with_and_without_normalisation():
    q = th.tensor([-2.0, -4.0], requires_grad=True)
    term, scale = value_term(q, False)
    assert (term.item(), scale.item()) == (3.0, 3.0)  # -mean(Q), and mean |Q| logged either way
    term.backward()
    assert q.grad.tolist() == [-0.5, -0.5]  # d(-mean Q)/dQ_i = -1/B
    q.grad = None
    term, _ = value_term(q, True)
    assert term.item() == pytest.approx(1.0)  # divided by 3, a detached scale
    term.backward()
    assert q.grad.tolist() == pytest.approx([-1 / 6, -1 / 6])


def test_actor_loss_without_normalisation_hand_computed():
    v, x0, x1 = chunks([1.0, 2.0]), chunks([0.0, 0.0]), chunks([1.0, 1.0])
    q = th.tensor([-2.0, -4.0])
    # flow 0.5 ; raw q_term = -mean(q) = 3 ; loss = 0.5 + 0.5 * 3 (normalised: 0.5 + 0.5 * 1)
    loss, info = actor_loss(v, x0, x1, q, q_weight=0.5, smooth_weight=0.0, normalize_q=False)
    assert loss.item() == pytest.approx(2.0)
    assert info["q_term"] == pytest.approx(3.0)


def test_drop_past_actions_with_a_seeded_generator():
    history = th.arange(1.0, 25.0).reshape(4, 3, 2)  # 4 samples, ℓ = 3, A = 2, no zeros
    generator = th.Generator().manual_seed(0)  # draws 0.4963, 0.7682, 0.0885, 0.1320
    dropped = drop_past_actions(history, 0.5, generator)
    # u < p drops: samples 0, 2, 3 are all zero, sample 1 is untouched
    assert dropped[[0, 2, 3]].abs().sum().item() == 0.0
    assert th.equal(dropped[1], history[1])
    assert th.equal(drop_past_actions(history, 1.0, th.Generator().manual_seed(0)), th.zeros_like(history))
    # p = 0: the input itself, and nothing drawn
    state = generator.get_state()
    assert drop_past_actions(history, 0.0, generator) is history
    assert th.equal(generator.get_state(), state)


# ------------------------------------------------------------------------------ the switches in the model
def test_defaults_leave_training_bit_identical():
    """The new arguments passed at their defaults train exactly as when they are not passed."""
    plain = trained()
    explicit = trained(**NEW_MODEL_DEFAULTS, policy_kwargs=NEW_POLICY_DEFAULTS)
    assert state_hash(plain) == state_hash(explicit)
    for key, value in plain.policy.state_dict().items():
        assert th.equal(value, explicit.policy.state_dict()[key]), key
    assert plain.policy.value_trained_actor() is plain.actor and not hasattr(plain.policy, "one_step_actor")


def test_defaults_are_the_documented_ones():
    model, policy = inspect.signature(UA2C.__init__).parameters, inspect.signature(UA2CPolicy.__init__).parameters
    assert {name: model[name].default for name in NEW_MODEL_DEFAULTS} == NEW_MODEL_DEFAULTS
    assert {name: policy[name].default for name in NEW_POLICY_DEFAULTS} == NEW_POLICY_DEFAULTS


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(past_action_dropout=1.5), r"past_action_dropout must be a number in \[0, 1\], got 1.5"),
        (dict(past_action_dropout=-0.1), r"past_action_dropout must be a number in \[0, 1\]"),
        (dict(normalize_q="yes"), "normalize_q must be a bool, got 'yes'"),
        (dict(distill_weight=-1.0), "distill_weight must be a finite number >= 0, got -1.0"),
        (dict(policy_kwargs=dict(actor_type="onestep")), r"actor_type must be one of \['flow', 'one_step'\]"),
        (dict(policy_kwargs=dict(actor_past_actions=1)), "actor_past_actions must be a bool, got 1"),
    ],
)
def test_bad_values_name_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", "Pendulum-v1", **kwargs)


def test_dropout_p1_is_the_objective_on_histories_without_past_actions():
    model = trained(steps=60)
    data = model.replay_buffer.sample(8)
    zeroed = data._replace(action_history=th.zeros_like(data.action_history))
    model.past_action_dropout = 1.0
    dropped = model_objective(model, data, generator=th.Generator().manual_seed(1))
    model.past_action_dropout = 0.0
    plain = model_objective(model, zeroed, generator=th.Generator().manual_seed(1))
    # x0 and tau are drawn first: the same draws, then every history loses its past actions
    assert dropped.loss.item() == plain.loss.item()
    assert model_objective(model, data, generator=th.Generator().manual_seed(1)).loss.item() != plain.loss.item()


def test_dropout_training_is_seeded():
    first, second = trained(past_action_dropout=0.5), trained(past_action_dropout=0.5)
    assert state_hash(first) == state_hash(second)
    assert state_hash(first) != state_hash(trained())


def test_actor_without_past_actions():
    policy = tiny_policy(actor_past_actions=False)
    assert policy.actor.history_layer.in_features == 2 * 3  # ℓ * obs_dim, no ℓ * action_dim
    assert tiny_policy().actor.history_layer.in_features == 2 * (3 + 2)
    obs, act = th.randn(4, 2, 3), th.randn(4, 2, 2)
    shifts = plan_sensitivity(policy, obs, act, th.Generator().manual_seed(0))
    assert shifts["sensitivity_past_actions"] == 0.0  # the plan cannot follow the past actions
    assert shifts["sensitivity_observations"] > 0.0


def test_one_step_policy_samples_candidates_in_one_call():
    policy = tiny_policy(actor_type="one_step")
    obs, act = th.randn(2, 2, 3), th.randn(2, 2, 2)
    x0 = th.randn(2, 5, 3, 2)
    history = policy.flatten_history(obs, act)
    with th.no_grad():
        expected = policy.one_step_actor(history, x0)
        assert th.equal(policy.sample_chunks(obs, act, 5, 7, x0=x0), expected)
        assert th.equal(policy.sample_chunks(obs, act, 5, 1, x0=x0), expected)  # Euler steps not used
        # each candidate is mu of its own noise: the first candidate alone gives the same chunk
        assert th.allclose(policy.one_step_actor(history, x0[:, :1]), expected[:, :1], atol=1e-6)
    # one optimizer trains both actors
    optimized = {id(p) for group in policy.actor.optimizer.param_groups for p in group["params"]}
    assert optimized == {id(p) for p in [*policy.actor.parameters(), *policy.one_step_actor.parameters()]}


def test_one_step_value_term_trains_mu_only():
    """QC-FQL: the flow learns by flow matching alone, the value term reaches the one-step policy."""
    model = trained(steps=60, policy_kwargs=ONE_STEP)
    data = model.replay_buffer.sample(8)

    def grads(q_weight: float) -> tuple[list[th.Tensor], list[th.Tensor]]:
        loss = model_objective(model, data, q_weight, th.Generator().manual_seed(2)).loss
        flow = th.autograd.grad(loss, list(model.actor.parameters()), retain_graph=True)
        return flow, th.autograd.grad(loss, list(model.policy.one_step_actor.parameters()))

    (flow_0, mu_0), (flow_q, mu_q) = grads(0.0), grads(10.0)
    assert all(th.equal(a, b) for a, b in zip(flow_0, flow_q, strict=True))
    assert any(not th.equal(a, b) for a, b in zip(mu_0, mu_q, strict=True))
    strength = value_term_strength(model, data, th.Generator().manual_seed(3))
    assert strength["q_grad_norm"] > 0.0 and strength["x_hat_shift"] > 0.0
    model.q_weight = 0.0
    assert value_term_strength(model, data, th.Generator().manual_seed(3))["q_grad_norm"] == 0.0


@pytest.mark.parametrize("normalize_q", [True, False])
def test_one_step_objective_recomputed_from_its_draws(normalize_q):
    """The objective draws x0, tau, then z, and sums flow + alpha * distillation - lambda * Q term."""
    model = trained(steps=60, policy_kwargs=ONE_STEP, q_weight=3.0, distill_weight=7.0, normalize_q=normalize_q)
    policy, data = model.policy, model.replay_buffer.sample(8)
    obs, act, x1 = data.observation_history, data.action_history, data.chunks
    generator = th.Generator().manual_seed(4)
    x0, tau = th.randn(x1.shape, generator=generator), th.rand(8, generator=generator)
    z = th.randn(x1.shape, generator=generator)
    with th.no_grad():
        x_tau = (1 - tau[:, None, None]) * x0 + tau[:, None, None] * x1
        error = (model.actor(x_tau, tau, policy.actor.condition(policy.flatten_history(obs, act))) - (x1 - x0)).pow(2) * data.chunk_mask[..., None]
        flow = error.sum() / (data.chunk_mask.sum() * x1.shape[-1])
        mu = policy.one_step_actor(policy.flatten_history(obs, act), z)
        distill = (mu - policy.actor.sample(policy.flatten_history(obs, act), z, policy.flow_steps)).pow(2).mean()
        q = model.critic(obs.flatten(1), mu.clamp(-1, 1).unsqueeze(1))[:, :, 0].min(dim=0).values
        q_term = -q.mean() / q.abs().mean() if normalize_q else -q.mean()
        expected = flow + 7.0 * distill + 3.0 * q_term
    objective = model_objective(model, data, generator=th.Generator().manual_seed(4))
    assert objective.loss.item() == pytest.approx(expected.item(), rel=1e-5)
    assert th.allclose(objective.chunks, mu)


def test_one_step_targets_and_acting_are_one_network():
    model = trained(steps=60, policy_kwargs=ONE_STEP)
    data = model.replay_buffer.sample(8)
    gap = policy_gap(model, data.observation_history, data.action_history, th.Generator().manual_seed(0))
    assert gap["spread_ratio"] == 1.0  # the same mu whatever the Euler steps, from the same noise
    report = diagnose(model, data)
    assert list(report) == list(METRICS) and all(np.isfinite(list(report.values())))


@pytest.mark.parametrize("critic_arch", ["transformer", "mlp"])
def test_one_step_model_trains_saves_and_loads(tmp_path, critic_arch):
    kwargs = dict(steps=300, past_action_dropout=0.2, normalize_q=False, distill_weight=10.0,
                  policy_kwargs=dict(ONE_STEP, critic_arch=critic_arch, actor_past_actions=False))
    if critic_arch == "mlp":
        kwargs["policy_kwargs"].update(critic_kwargs=dict(net_arch=[32, 32]))
    model = trained(**kwargs)
    assert state_hash(model) == state_hash(trained(**kwargs))  # seeded: bit-identical
    info = model_objective(model, model.replay_buffer.sample(8), generator=th.Generator().manual_seed(0)).info
    assert info["distill_loss"] > 0.0 and set(info) == {"flow_loss", "distill_loss", "q_term", "q_scale"}
    actions = rollout_actions(model)
    model.save(tmp_path / "model")
    loaded = UA2C.load(tmp_path / "model")
    assert (loaded.past_action_dropout, loaded.normalize_q, loaded.distill_weight) == (0.2, False, 10.0)
    assert loaded.policy.actor_type == "one_step" and loaded.policy.actor_past_actions is False
    np.testing.assert_array_equal(rollout_actions(loaded), actions)
    model.policy.save(tmp_path / "policy")
    np.testing.assert_array_equal(rollout_actions(UA2CPolicy.load(tmp_path / "policy")), actions)


class ConstantNoise(ActionNoise):
    """Exploration noise of +5 on every action, counting its draws."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def __call__(self) -> np.ndarray:
        self.calls += 1
        return np.full(1, 5.0)


def test_action_noise_reaches_the_executed_actions_and_the_chunks():
    noise = ConstantNoise()
    model = UA2C("MlpPolicy", "Pendulum-v1", action_noise=noise, seed=0, chunk_size=3, history_len=2,
                 online_targets="prefix", **{**FAST, "learning_starts": 30})  # fmt: skip
    model.learn(60)
    assert noise.calls == 30  # once per step after the warm-up of uniform random plans
    executed = model.replay_buffer.online.actions[:60, 0, 0]  # normalised
    assert np.all(executed[30:] == 1.0)  # +5, then clipped to the bounds
    assert np.all(np.abs(executed[:30]) < 1.0)  # warm-up: uniform random, no noise
    # the chunks (Eq. 8) of plans started after the warm-up hold the noisy executed actions
    starts = [t for t in range(31, 57) if model.replay_buffer.online.horizon[t, 0] > 0]
    assert starts
    for t in starts:
        horizon = int(model.replay_buffer.online.horizon[t, 0])
        assert np.all(model.replay_buffer.online.plans[t, 0, :horizon] == 1.0)


# ------------------------------------------------------------------------------ the paper preset
def test_preset_is_a_copy_and_names_unknown_presets():
    kwargs = preset("paper")
    assert kwargs == PAPER
    kwargs["policy_kwargs"]["net_arch"].append(7)
    assert PAPER["policy_kwargs"]["net_arch"] == [128, 128]
    with pytest.raises(ValueError, match=r"preset name must be one of \['paper'\], got 'recommended'"):
        preset("recommended")


#: where the defaults of this release leave the paper (docs/algorithm.md, "Defaults and the paper preset")
CHOSEN = {"gradient_steps": 1, "q_weight": 0.3, "flow_steps": 5, "exploration": "softmax", "net_arch": [256, 256],
          "n_elite": 8}


def test_defaults_leave_the_paper_preset_in_the_chosen_values_only():
    """The constructors' defaults are the paper preset but for six values chosen on validation: a model
    built with the preset and those six is the default model, bit for bit."""
    default = UA2C("MlpPolicy", "Pendulum-v1", seed=0)
    built = {name: getattr(default, name) for name in PAPER if name not in ("policy_kwargs", "execution_rule",
                                                                        "entropy_threshold")}
    built |= {"execution_rule": default.execution.rule, "entropy_threshold": default.execution.entropy_threshold,
              "train_freq": default.train_freq.frequency}  # SB3 converts it to a TrainFreq
    built |= {name: getattr(default.policy, name) for name in PAPER["policy_kwargs"]}
    paper = {**{k: v for k, v in PAPER.items() if k != "policy_kwargs"}, **PAPER["policy_kwargs"]}
    assert {name: value for name, value in built.items() if paper[name] != value} == CHOSEN
    assert list(DEFAULT_NET_ARCH) == CHOSEN["net_arch"]
    kwargs = preset("paper")
    kwargs.update(gradient_steps=1, q_weight=0.3, flow_steps=5, exploration="softmax")
    kwargs["policy_kwargs"].update(net_arch=[256, 256], n_elite=8)
    assert state_hash(UA2C("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)) == state_hash(default)
    paper_model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **preset("paper"))
    assert paper_model.policy.net_arch == [128, 128] and paper_model.policy.n_elite == 1
    assert (paper_model.gradient_steps, paper_model.q_weight, paper_model.exploration) == (-1, 1.0, "plan")
