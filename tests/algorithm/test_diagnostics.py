"""Diagnostics (sb3_ua2c.diagnostics): each metric on hand-made critics and actors whose answer is
known, the training log, and the command on a tiny checkpoint and dataset."""

import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import FAST, TINY, tiny_policy

from sb3_ua2c import UA2C
from sb3_ua2c import diagnostics as diag
from sb3_ua2c.buffers import ChunkReplaySamples
from sb3_ua2c.diagnostics.__main__ import main as diagnostics_main
from sb3_ua2c.offline import Episode, write_dataset


class FakeCritics(nn.Module):
    """Two critics ``(B, ℓ*obs_dim), (B, C, k, a) -> (2, B, C)`` given by ``fn(obs_flat, chunks, j)``."""

    def __init__(self, fn):
        super().__init__()
        self.fn = fn
        self.scale = nn.Parameter(th.ones(()))  # so that requires_grad_ has something to switch

    def forward(self, obs_flat, chunks):
        return th.stack([self.fn(obs_flat, chunks, j) * self.scale for j in range(2)])


def ignores_the_chunk(obs_flat, chunks, j):
    return (obs_flat.sum(-1, keepdim=True) + j).expand(chunks.shape[:2])  # (B, C)


def prefers_small_actions(obs_flat, chunks, j):
    return -chunks.pow(2).sum(dim=(-2, -1)) - j  # ignores the observations


def histories(m: int = 8):
    g = th.Generator().manual_seed(1)
    return th.randn(m, 2, 3, generator=g), th.rand(m, 2, 2, generator=g) * 2 - 1  # (m, ℓ, obs), (m, ℓ, act)


# ---------------------------------------------------------------------------- pure maths
def test_shift_and_correlation_by_hand():
    a, b = th.tensor([[0.0, 5.0], [1.0, 5.0]]), th.tensor([[0.5, -5.0], [0.0, 5.0]])
    assert diag.mean_abs_shift(a, b, [0]) == pytest.approx(0.75)  # (0.5 + 1) / 2, dim 1 left out
    assert math.isnan(diag.mean_abs_shift(a, b, []))
    x = th.tensor([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    assert diag.correlation(x, 2 * x + 1, [0]) == pytest.approx(1.0)
    assert diag.correlation(x, -x, [0]) == pytest.approx(-1.0)
    # y = (1, 3, 2): deviations (-1, 0, 1) and (-1, 1, 0): 1 / sqrt(2 * 2)
    assert diag.correlation(x, th.tensor([[1.0, 0], [3.0, 0], [2.0, 0]]), [0]) == pytest.approx(0.5)
    assert math.isnan(diag.correlation(x, x, [1]))  # a constant dim has no correlation


def test_candidate_spread_and_twin_agreement_by_hand():
    q = th.tensor([[[1.0, 3.0, 2.0], [0.0, 4.0, 1.0]],  # critic 1: best candidates 1 and 1
                   [[2.0, 5.0, 1.0], [3.0, 1.0, 0.0]]])  # critic 2: best candidates 1 and 0
    # min over critics: (1, 3, 1) with std sqrt(4/3) and (0, 1, 0) with std sqrt(1/3)
    assert diag.candidate_q_std(q) == pytest.approx((math.sqrt(4 / 3) + math.sqrt(1 / 3)) / 2)
    assert diag.twin_agreement(q) == 0.5


def test_critic_fit_by_hand():
    fit = diag.critic_fit(th.tensor([[1.0, 2.0], [3.0, 2.0]]), th.tensor([1.0, 0.0]))
    # errors (0, 2, 2, 2): RMSE sqrt(12 / 4); twin gap (|3 - 1| + |2 - 2|) / 2
    assert fit == pytest.approx({"td_rmse": math.sqrt(3.0), "twin_gap": 1.0})
    assert diag.critic_fit(th.tensor([[1.0, 2.0]]), th.tensor([1.0, 0.0]))["twin_gap"] == 0.0


# ---------------------------------------------------------------------------- model-level metrics
def test_an_actor_without_observations_is_insensitive_to_them():
    policy = tiny_policy(n_candidates=4)
    policy.critic = FakeCritics(prefers_small_actions)
    obs, act = histories()
    with th.no_grad():
        policy.actor.history_layer.weight[:, : 2 * 3] = 0.0  # the observation part of (o, a) histories
    sens = diag.plan_sensitivity(policy, obs, act, th.Generator().manual_seed(0))
    assert sens["sensitivity_observations"] == 0.0
    assert sens["sensitivity_past_actions"] > 0.01
    with th.no_grad():  # and one without past actions is insensitive to those
        policy.actor.history_layer.weight[:, 2 * 3 :] = 0.0
        policy.actor.history_layer.weight[:, : 2 * 3] = 0.5
    sens = diag.plan_sensitivity(policy, obs, act, th.Generator().manual_seed(0))
    assert sens["sensitivity_past_actions"] == 0.0
    assert sens["sensitivity_observations"] > 0.01


def test_a_critic_that_ignores_the_chunk_cannot_rank():
    policy = tiny_policy(n_candidates=5)
    policy.critic = FakeCritics(ignores_the_chunk)
    obs, act = histories()
    ranking = diag.candidate_ranking(policy, obs, act, th.Generator().manual_seed(0))
    # no spread; every critic's argmax of tied values is the first candidate: they always agree
    assert ranking == {"candidate_q_std": 0.0, "twin_agreement": 1.0}
    policy.critic = FakeCritics(lambda o, c, j: (1 - 2 * j) * c.sum(dim=(-2, -1)))  # opposite rankings
    assert diag.candidate_ranking(policy, obs, act, th.Generator().manual_seed(0))["twin_agreement"] == 0.0


def test_data_correlation_of_a_batch_where_the_next_action_follows_the_last():
    policy = tiny_policy(n_candidates=4)
    policy.critic = FakeCritics(prefers_small_actions)
    obs, act = histories()
    chunks = th.zeros(8, 3, 2)
    chunks[:, 0] = 0.5 * act[:, -1] - 0.1
    data = ChunkReplaySamples(obs, act, chunks, *[None] * 5)
    corr = diag.action_correlations(policy, data, th.Generator().manual_seed(0))
    assert corr["correlation_data"] == pytest.approx(1.0)
    assert -1.0 <= corr["correlation_policy"] <= 1.0


def pendulum_model(**kwargs) -> UA2C:
    return UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, history_len=2, **{**FAST, **kwargs})


def pendulum_batch(model: UA2C, m: int = 16) -> ChunkReplaySamples:
    g = th.Generator().manual_seed(2)
    obs = th.randn(m, 2, 3, generator=g)
    chunks = th.rand(m, 3, 1, generator=g) * 2 - 1
    mask = th.ones(m, 3)
    return ChunkReplaySamples(obs, th.zeros(m, 2, 1), chunks, th.zeros(m, 3), th.full((m,), 3.0), th.ones(m),
                              obs, th.zeros(m, 2, 1), mask)


def set_critics(model: UA2C, fn) -> None:
    model.policy.critic = model.critic = FakeCritics(fn)
    model.policy.critic_target = model.critic_target = FakeCritics(fn)


def test_value_term_strength_is_zero_without_a_value_gradient_and_linear_in_lambda():
    model = pendulum_model(q_weight=1.0)
    set_critics(model, lambda o, c, j: 10.0 + c.sum(dim=(-2, -1)))  # |Q| ≈ 10, dQ/dx̂1 = 1
    data = pendulum_batch(model)
    one = diag.value_term_strength(model, data, th.Generator().manual_seed(0))
    model.q_weight = 2.0
    two = diag.value_term_strength(model, data, th.Generator().manual_seed(0))
    assert two["flow_grad_norm"] == pytest.approx(one["flow_grad_norm"])
    assert two["q_grad_ratio"] == pytest.approx(2 * one["q_grad_ratio"], rel=1e-4)
    assert 0.0 < one["x_hat_shift"] <= two["x_hat_shift"] + 1e-9
    model.q_weight = 0.0
    zero = diag.value_term_strength(model, data, th.Generator().manual_seed(0))
    assert (zero["q_grad_norm"], zero["q_grad_ratio"], zero["x_hat_shift"]) == (0.0, 0.0, 0.0)
    model.q_weight = 1.0
    set_critics(model, ignores_the_chunk)
    assert diag.value_term_strength(model, data, th.Generator().manual_seed(0))["q_grad_norm"] == 0.0


def test_policy_gap_is_zero_when_the_targets_sample_as_the_policy_acts():
    model = pendulum_model(n_candidates=4, n_target_candidates=4, flow_steps=3, target_flow_steps=3,
                           policy_kwargs={**TINY, "n_elite": 1})
    set_critics(model, lambda o, c, j: c.sum(dim=(-2, -1)) - j)
    obs, act = pendulum_batch(model)[:2]
    gap = diag.policy_gap(model, obs, act, th.Generator().manual_seed(0))
    # the same candidates, the best of all 4 on both sides
    assert gap["policy_gap"] == 0.0 and gap["spread_ratio"] == 1.0
    assert gap["acting_value"] == gap["bootstrap_value"]
    model.n_target_candidates = 1  # the target sees one of the acting candidates: never more than the best
    assert diag.policy_gap(model, obs, act, th.Generator().manual_seed(0))["policy_gap"] >= 0.0


def test_training_logs_the_diagnostics_without_moving_the_random_streams(monkeypatch):
    def run(interval):
        monkeypatch.setattr(diag, "DIAGNOSTICS_INTERVAL", interval)
        model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
        model.learn(90)
        return model

    logged, quiet = run(3), run(10**9)
    for key, value in logged.policy.state_dict().items():
        assert th.equal(value, quiet.policy.state_dict()[key]), key
    keys = logged.logger.name_to_value
    for key in ("train/td_rmse", "train/twin_gap", "train/q_grad_ratio", "train/candidate_q_std",
                "train/twin_agreement"):
        assert key in keys and math.isfinite(keys[key]), key
    assert "train/q_grad_ratio" not in quiet.logger.name_to_value


# ---------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A tiny Pendulum-v1 checkpoint and a dataset of 3 random episodes of 30 steps."""
    root = tmp_path_factory.mktemp("diag")
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    model.save(root / "model.zip")
    rng = np.random.default_rng(0)
    episodes = []
    for _ in range(3):
        end = np.zeros(30, dtype=bool)
        end[-1] = True
        episodes.append(Episode(
            observations=rng.uniform(-1, 1, (31, 3)).astype(np.float32),
            actions=rng.uniform(-2, 2, (30, 1)).astype(np.float32),
            rewards=rng.normal(size=30), terminations=np.zeros(30, dtype=bool), truncations=end,
        ))
    write_dataset(episodes, root / "data", model.observation_space, model.action_space)
    write_dataset(episodes[:1], root / "other", gym.spaces.Box(-1, 1, (3,), np.float32), model.action_space)
    return root


def test_command_reports_every_metric(saved, capsys):
    out = saved / "report.json"
    code = diagnostics_main([str(saved / "model.zip"), str(saved / "data"), "--n-histories", "32", "--json", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    record = json.loads(out.read_text())
    assert list(record["metrics"]) == list(diag.METRICS)
    assert (record["n_histories"], record["seed"]) == (32, 0)
    for name in diag.METRICS:
        assert name in printed
    assert 0.0 <= record["metrics"]["twin_agreement"] <= 1.0
    # the same seed gives the same numbers
    again = saved / "again.json"
    diagnostics_main([str(saved / "model.zip"), str(saved / "data"), "--n-histories", "32", "--json", str(again)])
    assert json.loads(again.read_text())["metrics"] == pytest.approx(record["metrics"], nan_ok=True)


@pytest.mark.parametrize(("args", "message"), [
    (["missing.zip", "data"], "CHECKPOINT: no file"),
    (["model.zip", "missing"], "DATASET: no dataset"),
    (["model.zip", "other"], "observation_space"),
    (["model.zip", "data", "--n-histories", "1"], "--n-histories must be an integer >= 2"),
])
def test_command_rejects_bad_input(saved, capsys, args, message):
    paths = [str(saved / a) if i < 2 else a for i, a in enumerate(args)]
    assert diagnostics_main(paths) == 2
    err = capsys.readouterr().err
    assert message in err
    if "observation_space" in message:
        assert "DATASET" in err and "CHECKPOINT" in err
