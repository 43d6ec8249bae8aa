"""The prefix critic (``critic_type="prefix"``): targets of every prefix, the causal mask, the replay
samples it needs, candidate selection at ``L_t``, and the two actor-loss details (clamped x̂1,
padding left out of the flow loss)."""

import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import ACT, OBS

from sb3_ua2c import UA2C
from sb3_ua2c.buffers import ChunkReplayBuffer
from sb3_ua2c.chunking import (
    chunk_critic_loss,
    chunk_target,
    prefix_bellman_targets,
    prefix_target_mask,
    q_at_length,
)
from sb3_ua2c.flow import flow_matching_loss
from sb3_ua2c.policies import ChunkCritics, UA2CPolicy

T = th.tensor


# ---------------------------------------------------------------------------------------- targets
# k = 3, gamma = 0.5, V(h_{t+1}) = 10, V(h_{t+2}) = 20, V(h_{t+3}) = 40; the caller passes
# V(h_{t+min(u, L)}), so a window cut after L = 2 steps repeats V(h_{t+2}) at u = 3.
@pytest.mark.parametrize(
    ("rewards", "horizon", "bootstrap", "values", "expected"),
    [
        # a normal window: y_1 = 1 + .5*10, y_2 = 1 + .5*2 + .25*20, y_3 = 1 + 1 + .25*3 + .125*40
        ([1.0, 2.0, 3.0], 3, 1.0, [10.0, 20.0, 40.0], [6.0, 7.0, 7.75]),
        # the episode terminates at the window's last step: y_3 = 1 + 1 + .75, no bootstrap
        ([1.0, 2.0, 3.0], 3, 0.0, [10.0, 20.0, 40.0], [6.0, 7.0, 2.75]),
        # a termination after 2 steps: y_2 = y_3 = 1 + .5*2, the terminal return
        ([1.0, 2.0, 0.0], 2, 0.0, [10.0, 20.0, 20.0], [6.0, 2.0, 2.0]),
        # a truncation after 2 steps: y_2 = y_3 = 1 + .5*2 + .25*V(h_{t+2}) (gamma^2: 2 steps happened)
        ([1.0, 2.0, 0.0], 2, 1.0, [10.0, 20.0, 20.0], [6.0, 7.0, 7.0]),
        # a termination after 1 step: every prefix gets r_t
        ([1.0, 0.0, 0.0], 1, 0.0, [10.0, 10.0, 10.0], [1.0, 1.0, 1.0]),
    ],
)
def test_prefix_bellman_targets_hand_computed(rewards, horizon, bootstrap, values, expected):
    y = prefix_bellman_targets(T([rewards]), T([horizon]), T([bootstrap]), T([values]), gamma=0.5)
    assert y.tolist() == [pytest.approx(expected)]
    # y_L is the chunk target of Eq. 4 / 8 with horizon L
    y_l = chunk_target(T([rewards]), T([horizon]), T([bootstrap]), T([values[horizon - 1]]), 0.5)
    assert y[0, horizon - 1].item() == pytest.approx(y_l.item())


def test_prefix_bellman_targets_for_k1_are_the_chunk_target():
    rewards, horizon, boot, v = T([[2.0], [3.0]]), T([1, 1]), T([1.0, 0.0]), T([[4.0], [5.0]])
    y = prefix_bellman_targets(rewards, horizon, boot, v, gamma=0.9)
    assert y.squeeze(-1).tolist() == pytest.approx([2.0 + 0.9 * 4.0, 3.0])
    assert th.equal(y.squeeze(-1), chunk_target(rewards, horizon, boot, v.squeeze(-1), 0.9))


def test_prefix_target_mask_and_masked_critic_loss():
    # an online plan that stopped after L_t = 2 of 3 trains Q_1, Q_2; one cut by an episode end all
    mask = prefix_target_mask(T([2, 2, 3]), T([False, True, False]), 3)
    assert mask.tolist() == [[True, True, False], [True, True, True], [True, True, True]]
    q = T([[[1.0, 2.0, 100.0]], [[0.0, 0.0, 100.0]]])  # (n=2, B=1, k=3); Q_3 has no target
    y = T([[0.0, 0.0, 0.0]])
    # critic 1: (1 + 4) / 2, critic 2: 0
    assert chunk_critic_loss(q, y, T([[True, True, False]])).item() == pytest.approx(2.5)


def test_q_at_length_picks_the_executed_prefix():
    q = th.arange(2 * 2 * 3, dtype=th.float32).reshape(2, 2, 3)  # (n=2, B=2, k=3)
    assert q_at_length(q, T([1, 3])).tolist() == [[0.0, 5.0], [6.0, 11.0]]
    q4 = th.arange(2 * 1 * 2 * 3, dtype=th.float32).reshape(2, 1, 2, 3)  # (n, m=1, S=2, k)
    assert q_at_length(q4, T([[2]])).tolist() == [[[1.0, 4.0]], [[7.0, 10.0]]]


# ---------------------------------------------------------------------------------------- critic
@pytest.mark.parametrize(("n_layers", "n_heads"), [(1, 1), (2, 2)])
def test_causal_mask_q_u_ignores_the_actions_after_u(n_layers, n_heads):
    th.manual_seed(0)
    critic = ChunkCritics(6, 4, 2, embed_dim=8, n_layers=n_layers, n_heads=n_heads, ff_dim=16, prefix=True)
    obs, chunks = th.randn(3, 6), th.randn(3, 2, 4, 2)
    q = critic(obs, chunks)
    assert q.shape == (2, 3, 2, 4)
    for u in range(1, 4):  # change the action at position u + 1 (index u)
        changed = chunks.clone()
        changed[:, :, u] += 0.7
        q_changed = critic(obs, changed)
        assert th.equal(q_changed[..., :u], q[..., :u])  # Q_1..Q_u exactly unchanged
        assert (q_changed[..., u] != q[..., u]).all()  # Q_{u+1} reads it


def test_k1_prefix_critic_is_the_chunk_critic():
    th.manual_seed(1)
    chunk = ChunkCritics(6, 1, 2, embed_dim=8, ff_dim=16)
    prefix = ChunkCritics(6, 1, 2, embed_dim=8, ff_dim=16, prefix=True)
    prefix.load_state_dict(chunk.state_dict())  # the same parameters
    obs, chunks = th.randn(5, 6), th.randn(5, 3, 1, 2)
    assert th.equal(prefix(obs, chunks)[..., 0], chunk(obs, chunks))


def test_prefix_critic_shares_the_chunk_critics_parameters():
    chunk = ChunkCritics(6, 4, 2, embed_dim=8, ff_dim=16)
    prefix = ChunkCritics(6, 4, 2, embed_dim=8, ff_dim=16, prefix=True)
    assert prefix.state_dict().keys() == chunk.state_dict().keys()


class _FirstActionCritic(nn.Module):
    """Q_1 = first action, Q_u = -first action for u > 1 (two critics, shape (2, m, S, k))."""

    def forward(self, obs_history, chunks):
        first = chunks[:, :, 0, 0]  # (m, S)
        k = chunks.shape[2]
        sign = th.tensor([1.0] + [-1.0] * (k - 1))
        return (first.unsqueeze(-1) * sign).expand(2, *first.shape, k)


@pytest.mark.parametrize(("threshold", "pick"), [(-1e9, "max"), (float("inf"), "min")])
def test_candidates_are_ranked_by_q_at_the_executed_length(threshold, pick):
    policy = UA2CPolicy(
        OBS, ACT, lambda _: 1e-3, chunk_size=3, history_len=2, n_candidates=8, entropy_threshold=threshold,
        critic_type="prefix",
    )
    policy.critic = _FirstActionCritic()
    generator = th.Generator().manual_seed(0)
    samples = policy.sample_chunks(policy.actor.condition(th.zeros(1, 4)), 8, policy.flow_steps, generator)
    chunks, lengths, _ = policy.plan_tensors(
        th.zeros(1, 2, 1), th.zeros(1, 2, 1), th.Generator().manual_seed(0)
    )
    first = samples.clamp(-1, 1)[0, :, 0, 0]
    assert lengths.item() == (1 if pick == "max" else 3)
    assert chunks[0, 0, 0].item() == (first.max() if pick == "max" else first.min()).item()


# ---------------------------------------------------------------------------------------- buffer
def offline_buffer(prefix_targets, k=3, ell=2):
    buf = ChunkReplayBuffer(32, OBS, ACT, "cpu", chunk_size=k, history_len=ell, prefix_targets=prefix_targets)
    # o_i = i, a_i = (i + 1) / 10, r_i = i + 1; terminated after the 4th step, whose next observation is 99
    buf.add_offline_episodes(
        [
            dict(
                observations=np.arange(4.0)[:, None],
                next_observations=np.array([[1.0], [2.0], [3.0], [99.0]]),
                actions=np.arange(1, 5)[:, None] / 10,
                rewards=np.arange(1.0, 5.0),
                terminations=np.array([False, False, False, True]),
                truncations=np.zeros(4, bool),
            )
        ]
    )
    return buf


def by_start(samples):
    """Sample fields keyed by the start observation o_t, as plain lists."""
    out = {}
    for i in range(samples.chunks.shape[0]):
        key = samples.observation_history[i, -1, 0].item()
        out[key] = {
            name: getattr(samples, name)[i].flatten().tolist()
            for name in samples._fields
            if getattr(samples, name) is not None
        }
    return out


def test_offline_all_prefixes_with_a_termination_inside_the_window():
    got = by_start(offline_buffer("all").sample(128))
    assert set(got) == {0.0, 1.0, 2.0, 3.0}
    s = got[2.0]  # o_2, o_3 then the end: L = 2, terminated
    assert s["horizons"] == [2.0] and s["bootstrap"] == [0.0]
    assert s["prefix_mask"] == [1.0, 1.0, 1.0]  # the prefix past the end gets the terminal return
    assert s["chunk_mask"] == [1.0, 1.0, 0.0]  # the zero padding after the end
    assert s["chunks"] == pytest.approx([0.3, 0.4, 0.0])
    assert s["rewards"] == [3.0, 4.0, 0.0]
    # h_{t+min(u, L)}, u = 1, 2, 3: (o_3, o_4 = 99) repeats at u = 3
    assert s["prefix_observation_history"] == [2.0, 3.0, 3.0, 99.0, 3.0, 99.0]
    assert s["prefix_action_history"] == pytest.approx([0.2, 0.3, 0.3, 0.4, 0.3, 0.4])
    assert s["next_observation_history"] == [3.0, 99.0]  # h_{t+L}, as for the chunk critic
    full = got[0.0]  # a full window from the episode start
    assert full["horizons"] == [3.0] and full["bootstrap"] == [1.0] and full["chunk_mask"] == [1.0] * 3
    assert full["prefix_observation_history"] == [0.0, 1.0, 1.0, 2.0, 2.0, 3.0]
    assert full["prefix_action_history"] == pytest.approx([0.0, 0.1, 0.1, 0.2, 0.2, 0.3])
    y = prefix_bellman_targets(T([s["rewards"]]), T([2]), T([0.0]), T([[7.0, 8.0, 8.0]]), 0.5)
    assert y.tolist() == [pytest.approx([3.0 + 0.5 * 7.0, 5.0, 5.0])]


def test_offline_sampled_prefix_is_the_target_of_one_u():
    samples = offline_buffer("sampled").sample(256)
    assert samples.prefix_mask is None and samples.prefix_observation_history is None
    true_horizon = {0.0: 3, 1.0: 3, 2.0: 2, 3.0: 1}
    seen = set()
    for i in range(256):
        t = samples.observation_history[i, -1, 0].item()
        u, big_l = int(samples.prefix_lengths[i]), true_horizon[t]
        seen.add(u)
        h = min(u, big_l)
        assert samples.horizons[i].item() == h
        # bootstrap inside the episode, at the terminal step not (the episode terminates at t = 3)
        assert samples.bootstrap[i].item() == float(t + h < 4)
        assert samples.rewards[i].tolist() == [t + 1 + j if j < h else 0.0 for j in range(3)]
        assert samples.next_observation_history[i, -1, 0].item() == (99.0 if t + h == 4 else t + h)
        assert samples.chunk_mask[i].tolist() == [1.0 if j < big_l else 0.0 for j in range(3)]
    assert seen == {1, 2, 3}  # uniform over the prefixes of a window


def add(buf, obs, plan=None, length=0, start=False, terminated=False, truncated=False):
    buf.add(
        np.array([[obs]], np.float32),
        np.array([[obs + 1]], np.float32),
        np.array([[obs / 10]], np.float32),
        np.array([1.0]),
        np.array([terminated]),
        np.array([truncated]),
        np.array([start]),
        np.array([plan is not None]),
        np.zeros((1, 3, 1), np.float32) if plan is None else np.array(plan, np.float32).reshape(1, 3, 1),
        np.array([length]),
    )


@pytest.mark.parametrize("prefix_targets", ["all", "sampled"])
def test_online_plans_train_the_executed_prefixes(prefix_targets):
    buf = ChunkReplayBuffer(32, OBS, ACT, "cpu", chunk_size=3, history_len=2, prefix_targets=prefix_targets)
    add(buf, 0.0, plan=[0.5, 0.6, 0.7], length=2, start=True)  # L_t = 2, executed in full
    add(buf, 1.0)
    add(buf, 2.0, plan=[0.8, 0.9, 1.0], length=3)
    add(buf, 3.0, terminated=True)  # cut after 2 of 3 steps by a termination
    add(buf, 10.0, plan=[0.1, 0.2, 0.3], length=3, start=True)
    add(buf, 11.0, truncated=True)  # cut after 2 of 3 steps by a truncation
    got = by_start(buf.sample(64))
    assert set(got) == {0.0, 2.0, 10.0}
    horizons = {0.0: ([2.0], [1.0]), 2.0: ([2.0], [0.0]), 10.0: ([2.0], [1.0])}
    for t, (horizon, bootstrap) in horizons.items():
        assert got[t]["horizons"] == horizon and got[t]["bootstrap"] == bootstrap
        assert got[t]["chunk_mask"] == [1.0, 1.0, 1.0]  # a plan's tail is a planned action, not padding
    if prefix_targets == "sampled":  # the executed prefix
        assert [got[t]["prefix_lengths"] for t in (0.0, 2.0, 10.0)] == [[2.0]] * 3
    else:  # Q_3 of a plan executed for L_t = 2 has no target; past an episode end it has one
        assert got[0.0]["prefix_mask"] == [1.0, 1.0, 0.0]
        assert got[2.0]["prefix_mask"] == [1.0, 1.0, 1.0]
        assert got[10.0]["prefix_mask"] == [1.0, 1.0, 1.0]
        assert got[10.0]["prefix_observation_history"] == [10.0, 11.0, 11.0, 12.0, 11.0, 12.0]


def test_bad_prefix_targets_raise():
    with pytest.raises(ValueError, match="prefix_targets"):
        ChunkReplayBuffer(32, OBS, ACT, "cpu", chunk_size=3, history_len=2, prefix_targets="every")


# ---------------------------------------------------------------------------------------- actor loss
def test_flow_loss_ignores_padding():
    v = T([[[1.0], [2.0], [5.0]]])  # (B=1, k=3, A=1); x1 - x0 = 0
    x = th.zeros(1, 3, 1)
    assert flow_matching_loss(v, x, x).item() == pytest.approx((1 + 4 + 25) / 3)
    assert flow_matching_loss(v, x, x, T([[1.0, 1.0, 0.0]])).item() == pytest.approx((1 + 4) / 2)
    assert flow_matching_loss(v, x, x, T([[1.0, 1.0, 1.0]])).item() == pytest.approx((1 + 4 + 25) / 3)


@pytest.mark.parametrize("clip", [True, False])
def test_actor_value_term_sees_clamped_chunks(clip):
    """x̂1 of an untrained actor leaves [-1, 1]; the critics see it clamped, and the clamped entries
    get no value gradient (the flow term still pulls them back). ``clip_actor_chunk=False``: Eq. 2 as is."""
    model = UA2C(
        "MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, batch_size=64, seed=0, clip_actor_chunk=clip
    )
    seen = []
    model.critic.register_forward_pre_hook(lambda _, args: seen.append(args[1].detach().clone()))
    b = 64
    data = offline_buffer(None).sample(b)._replace(
        observation_history=th.zeros(b, 2, 3), chunks=th.full((b, 3, 1), 0.9)
    )
    th.manual_seed(0)
    model._actor_loss(data, th.zeros(b, 6))
    assert (seen[0].abs().max().item() <= 1.0) == clip
    x = T([[[2.2], [0.3], [-1.5]]], requires_grad=True)
    y = x.clamp(-1.0, 1.0)  # what _actor_loss does
    y.sum().backward()
    assert y.flatten().tolist() == pytest.approx([1.0, 0.3, -1.0]) and x.grad.flatten().tolist() == [0, 1, 0]


# ---------------------------------------------------------------------------------------- algorithm
@pytest.mark.parametrize(
    ("name", "kwargs"),
    [
        ("critic_type", {"critic_type": "value"}),
        ("prefix_targets", {"prefix_targets": 3}),
        ("clip_actor_chunk", {"clip_actor_chunk": "yes"}),
        ("mask_flow_padding", {"mask_flow_padding": 1}),
    ],
)
def test_bad_arguments_raise(name, kwargs):
    with pytest.raises(ValueError, match=name):
        UA2C("MlpPolicy", "Pendulum-v1", **kwargs)


def test_critic_type_is_not_a_policy_kwarg():
    with pytest.raises(ValueError, match="critic_type"):
        UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs={"critic_type": "prefix"})
    with pytest.raises(ValueError, match="critic_type"):
        UA2CPolicy(OBS, ACT, lambda _: 1e-3, critic_type="Prefix")


def small(prefix_targets="all", **kwargs):
    return UA2C(
        "MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, learning_starts=60, batch_size=16,
        n_candidates=4, critic_type="prefix", prefix_targets=prefix_targets, seed=3, **kwargs,
    )


@pytest.mark.parametrize("prefix_targets", ["all", "sampled"])
def test_seeded_runs_are_bit_identical(prefix_targets):
    a, b = small(prefix_targets).learn(120), small(prefix_targets).learn(120)
    assert a._n_updates > 0
    for x, y in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert th.equal(x, y)


def test_save_load_gives_identical_actions(tmp_path):
    model = small().learn(100)
    model.save(tmp_path / "prefix")
    loaded = UA2C.load(tmp_path / "prefix")
    assert loaded.critic_type == "prefix" and loaded.policy.critic.prefix
    obs = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    for m in (model, loaded):
        m.policy.set_training_mode(False)
    a, _ = model.predict(obs, deterministic=True)
    b, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("masked", [True, False])
def test_actor_loss_gets_the_padding_mask(monkeypatch, masked):
    import sb3_ua2c.ua2c as ua2c_module

    model = UA2C("MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, seed=0, mask_flow_padding=masked)
    data = offline_buffer(None).sample(32)
    data = data._replace(observation_history=th.zeros(32, 2, 3))
    got, original = {}, ua2c_module.actor_loss

    def spy(*args):
        got["mask"] = args[-1]
        return original(*args)

    monkeypatch.setattr(ua2c_module, "actor_loss", spy)
    model._actor_loss(data, th.zeros(32, 6))
    assert th.equal(got["mask"], data.chunk_mask) if masked else got["mask"] is None
    assert (data.chunk_mask == 0).any()  # windows cut by the episode end are in the batch
