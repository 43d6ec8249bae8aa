"""The MLP chunk critics (``critic_arch="mlp"``): hand-computed values, members as independent MLPs,
the shared history features, and the SB3 contract of a policy built with them."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import FAST, rollout_actions, tiny_policy

from sb3_ua2c import UA2C
from sb3_ua2c.critics import CRITICS, MLPChunkCritics, critic_defaults, make_critic
from sb3_ua2c.policies import UA2CPolicy

MLP = dict(FAST, policy_kwargs=dict(net_arch=[32, 32], critic_arch="mlp", critic_kwargs=dict(net_arch=[32, 32])))


def test_one_hidden_unit_by_hand():
    # Q = w_out * relu(w_h . h + w_a . a + b) + b_out, one critic, no norm
    critics = MLPChunkCritics(2, 2, 1, n_critics=1, activation_fn=nn.ReLU, net_arch=[1], layer_norm=False)
    with th.no_grad():
        critics.obs_layer.weight.copy_(th.tensor([[[1.0], [-2.0]]]))  # (1, 2, 1)
        critics.obs_layer.bias.fill_(0.5)
        critics.chunk_layer.weight.copy_(th.tensor([[[3.0], [1.0]]]))  # (1, k*a = 2, 1)
        critics.head.weight.fill_(2.0)
        critics.head.bias.fill_(-1.0)
    history = th.tensor([[1.0, 1.0]])  # w_h . h + b = 1 - 2 + 0.5 = -0.5
    chunks = th.tensor([[[[0.5], [0.0]], [[-1.0], [1.0]]]])  # (B=1, C=2, k=2, a=1): w_a . a = 1.5, -2
    q = critics(history, chunks)
    # candidate 0: relu(1.0) * 2 - 1 = 1; candidate 1: relu(-2.5) * 2 - 1 = -1
    assert q.shape == (1, 1, 2)
    assert q.tolist() == [[[1.0, -1.0]]]


def test_layer_norm_by_hand():
    # two hidden units: after the layer norm a pair (x, y) becomes (±1, ∓1) (gain 1, bias 0, eps 1e-5)
    critics = MLPChunkCritics(1, 1, 1, n_critics=1, activation_fn=nn.Identity, net_arch=[2], layer_norm=True)
    with th.no_grad():
        critics.obs_layer.weight.copy_(th.tensor([[[1.0, 0.0]]]))
        critics.obs_layer.bias.zero_()
        critics.chunk_layer.weight.copy_(th.tensor([[[0.0, 1.0]]]))
        critics.head.weight.copy_(th.tensor([[[3.0], [1.0]]]))
        critics.head.bias.zero_()
    q = critics(th.tensor([[4.0]]), th.tensor([[[[2.0]]]]))  # pre-norm (4, 2) -> (1, -1) -> 3 - 1
    assert q.item() == pytest.approx(2.0 * 1.0 / np.sqrt(1.0 + 1e-5), abs=1e-6)


@pytest.mark.parametrize("layer_norm", [True, False])
def test_each_member_is_an_ordinary_mlp_over_the_flattened_input(layer_norm):
    th.manual_seed(0)
    critics = MLPChunkCritics(6, 3, 2, n_critics=3, activation_fn=nn.SiLU, net_arch=[16, 8], layer_norm=layer_norm)
    with th.no_grad():  # random norm gains and biases, so that a member mixing them up would show
        for p in critics.parameters():
            p.add_(0.1 * th.randn_like(p))
    history, chunks = th.randn(4, 6), th.randn(4, 5, 3, 2)
    q = critics(history, chunks)  # (3, 4, 5)
    flat = th.cat([history.unsqueeze(1).expand(4, 5, 6), chunks.flatten(2)], dim=-1)  # (4, 5, 6 + 3*2)
    for j in range(3):
        first = nn.Linear(12, 16)
        first.weight.data = th.cat([critics.obs_layer.weight[j], critics.chunk_layer.weight[j]]).T
        first.bias.data = critics.obs_layer.bias[j, 0]
        second = nn.Linear(16, 8)
        second.weight.data, second.bias.data = critics.hidden[0].weight[j].T, critics.hidden[0].bias[j, 0]
        head = nn.Linear(8, 1)
        head.weight.data, head.bias.data = critics.head.weight[j].T, critics.head.bias[j, 0]
        layers = [first]
        for width, norm, linear in ((16, critics.norms[0], second), (8, critics.norms[1], head)):
            if layer_norm:
                ln = nn.LayerNorm(width)
                ln.weight.data, ln.bias.data = norm.weight[j, 0], norm.bias[j, 0]
                layers.append(ln)
            layers += [nn.SiLU(), linear]
        expected = nn.Sequential(*layers)(flat).squeeze(-1)  # (4, 5)
        th.testing.assert_close(q[j], expected, rtol=1e-5, atol=1e-5)


def test_candidates_share_their_history():
    th.manual_seed(1)
    critics = MLPChunkCritics(4, 2, 3, n_critics=2, activation_fn=nn.SiLU, net_arch=[256, 256], layer_norm=True)
    history, chunks = th.randn(3, 4), th.randn(3, 7, 2, 3)
    together = critics(history, chunks)  # (2, 3, 7)
    one_by_one = critics(history.repeat_interleave(7, 0), chunks.reshape(21, 1, 2, 3)).reshape(2, 3, 7)
    th.testing.assert_close(together, one_by_one, rtol=1e-6, atol=1e-6)


def test_policy_builds_the_chosen_critic_and_its_default_size():
    policy = tiny_policy(critic_arch="mlp")
    assert isinstance(policy.critic, MLPChunkCritics)
    assert isinstance(policy.critic_target, MLPChunkCritics)
    assert [layer.weight.shape[-1] for layer in policy.critic.hidden] == [256]  # SAC's 256 x 256
    assert policy.critic.obs_layer.weight.shape == (2, 2 * 3, 256)  # (n, ℓ*obs, h)
    assert all(th.equal(a, b) for a, b in zip(policy.critic.parameters(), policy.critic_target.parameters(), strict=True))
    no_norm = tiny_policy(critic_arch="mlp", critic_kwargs=dict(net_arch=[8], layer_norm=False))
    assert all(isinstance(norm, nn.Identity) for norm in no_norm.critic.norms)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(critic_arch="cnn"), r"critic_arch must be one of \['transformer', 'mlp'\]"),
        (dict(critic_arch="mlp", critic_kwargs=dict(net_arch=[])), r"critic_kwargs\['net_arch'\] must be a non-empty list"),
        (dict(critic_arch="mlp", critic_kwargs=dict(net_arch=[64, 0])), r"critic_kwargs\['net_arch'\] must be a non"),
        (dict(critic_kwargs=dict(net_arch=[64])), "unknown critic_kwargs key 'net_arch' for critic_arch='transformer'"),
        (dict(critic_arch="mlp", critic_kwargs=dict(layer_norm="yes")), r"critic_kwargs\['layer_norm'\] must be a bool"),
        (dict(critic_kwargs=dict(embed_dim=30, n_heads=4)), r"critic_kwargs\['n_heads'\]=4 must divide"),
        (dict(critic_kwargs=dict(embed_dim=0)), r"critic_kwargs\['embed_dim'\] must be an integer >= 1"),
        (dict(critic_kwargs=[32]), "critic_kwargs must be a dict or None"),
    ],
)
def test_bad_critic_arguments_name_the_parameter(kwargs, match):
    with pytest.raises(ValueError, match=match):
        tiny_policy(**{"critic_kwargs": None, **kwargs})
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs=kwargs)


def test_mlp_critic_model_save_load_and_policy_only_load_act_the_same(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **MLP).learn(120)
    model.save(tmp_path / "model.zip")
    model.policy.save(str(tmp_path / "policy.pt"))
    loaded = UA2C.load(tmp_path / "model.zip")
    policy = UA2CPolicy.load(str(tmp_path / "policy.pt"))
    assert loaded.policy.critic_arch == policy.critic_arch == "mlp"
    assert loaded.policy.critic_kwargs == policy.critic_kwargs == {"net_arch": [32, 32], "layer_norm": True}
    expected = rollout_actions(model)
    np.testing.assert_array_equal(rollout_actions(loaded), expected)
    np.testing.assert_array_equal(rollout_actions(policy), expected)


def test_mlp_critic_seeded_runs_are_bit_identical():
    def run() -> list[th.Tensor]:
        return [p.detach().clone() for p in UA2C("MlpPolicy", "Pendulum-v1", seed=3, **MLP).learn(150).policy.parameters()]

    assert all(th.equal(a, b) for a, b in zip(run(), run(), strict=True))


def test_mlp_critic_learns_the_reward_of_a_one_step_bandit():
    # one state, reward = -a^2, episodes of one step: Q(a) must rank a = 0 above |a| = 1
    env = gym.wrappers.TimeLimit(_Bandit(), max_episode_steps=1)
    model = UA2C("MlpPolicy", env, chunk_size=1, history_len=1, seed=0, gamma=0.0,
                 **{**MLP, "learning_starts": 64, "batch_size": 64})
    model.learn(600)
    chunks = th.tensor([-1.0, 0.0, 1.0]).reshape(1, 3, 1, 1)
    q = model.critic(th.zeros(1, 1), chunks).mean(0)[0]  # (3,)
    assert q[1] > q[0] + 0.3 and q[1] > q[2] + 0.3


class _Bandit(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        return np.zeros(1, np.float32), -float(action[0]) ** 2, True, False, {}


@pytest.mark.parametrize(
    "name",
    ["critic_embed_dim", "critic_n_layers", "critic_n_heads", "critic_ff_dim", "critic_net_arch", "critic_layer_norm"],
)
def test_the_flat_critic_arguments_of_the_earlier_layout_say_what_replaced_them(name):
    with pytest.raises(ValueError, match=rf"policy_kwargs\['{name}'\] is no longer an argument: use critic_kwargs="):
        UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs={name: 1})


def test_registry_and_make_critic():
    assert CRITICS == {"transformer": CRITICS["transformer"], "mlp": MLPChunkCritics}
    assert critic_defaults("mlp") == {"net_arch": (256, 256), "layer_norm": True}
    critics = make_critic("mlp", 6, 3, 2, 2, nn.SiLU, {"net_arch": [8]})
    assert critics(th.zeros(4, 6), th.zeros(4, 5, 3, 2)).shape == (2, 4, 5)  # (n_critics, B, C)
    with pytest.raises(ValueError, match="critic_arch must be one of"):
        make_critic("gru", 6, 3, 2, 2, nn.SiLU, None)


def test_a_new_critic_is_one_class_and_one_registry_line(monkeypatch):
    """docs/algorithm.md, "Adding a critic or an actor": the policy builds, trains and saves a critic
    registered by name, with its own kwargs."""

    class MeanCritics(nn.Module):
        def __init__(self, obs_history_dim, chunk_size, action_dim, n_critics, activation_fn, scale: float = 1.0):
            super().__init__()
            self.n_critics, self.scale = n_critics, scale
            self.weight = nn.Parameter(th.zeros(n_critics, 1, 1))

        def forward(self, obs_history, chunks):
            b, c = chunks.shape[:2]
            mean = chunks.reshape(b, c, -1).mean(-1)  # (B, C)
            return self.scale * mean.unsqueeze(0) + self.weight.reshape(-1, 1, 1)  # (n, B, C)

    monkeypatch.setitem(CRITICS, "mean", MeanCritics)
    model = UA2C("MlpPolicy", "Pendulum-v1", **dict(MLP, policy_kwargs=dict(
        net_arch=[16], critic_arch="mean", critic_kwargs=dict(scale=2.0))))
    model.learn(60)
    assert isinstance(model.critic, MeanCritics) and model.critic.scale == 2.0
    assert not th.equal(model.critic.weight, th.zeros(2, 1, 1))  # trained
