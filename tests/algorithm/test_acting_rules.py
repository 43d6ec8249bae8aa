"""Acting rules: the selections of a replanning (hand-computed weights) and the executions ``replan`` and
``ensemble`` (ACT's temporal ensembling, hand-computed), on the policy, through ``predict`` and save/load."""

import math

import numpy as np
import pytest
import torch as th

from sb3_ua2c import UA2C, ExecutionRule
from sb3_ua2c.chunking import select_candidates, uncertainty_weights, weighted_chunk
from sb3_ua2c.execution import AdaptiveChunkExecutor, PlanResult
from tests.ua2c_helpers import FAST, rollout_actions, tiny_policy


# ------------------------------------------------------------------------------ selections, by hand
def test_uncertainty_weights_by_hand():
    # twin critics, one history, three candidates: disagreement |Q1 − Q2| = 0, 2, 0 -> tau = 2/3;
    # mean Q = 1, 3, 3 -> softmax(1.5, 4.5, 4.5) = (e^-3, 1, 1) / (e^-3 + 2)
    q = th.tensor([[[1.0, 2.0, 3.0]], [[1.0, 4.0, 3.0]]])  # (n=2, m=1, S=3)
    w = uncertainty_weights(q)
    z = math.exp(-3.0) + 2.0
    assert w.tolist()[0] == pytest.approx([math.exp(-3.0) / z, 1 / z, 1 / z], rel=1e-5)


def test_uncertainty_weights_follow_the_ranking_as_far_as_it_exceeds_the_disagreement():
    spread = th.tensor([0.0, 1.0, 2.0, 3.0])
    agree = th.stack([spread * 10, spread * 10 + 0.1])[:, None]  # ranking 10 per step, disagreement 0.1
    unsure = th.stack([spread * 0.1, spread * 0.1 + 10.0])[:, None]  # ranking 0.1 per step, disagreement 10
    assert uncertainty_weights(agree)[0, -1] > 0.999  # acts like the best candidate
    assert uncertainty_weights(unsure)[0].tolist() == pytest.approx([0.25] * 4, abs=0.01)  # like the mean


def test_uncertainty_weights_refuse_a_single_critic():
    with pytest.raises(ValueError, match="at least 2 critics"):
        uncertainty_weights(th.zeros(1, 2, 4))


def test_weighted_chunk_averages_continuous_dims_and_keeps_the_lead_candidate_category():
    cands = th.tensor([[[[0.0, -1.0]], [[1.0, 1.0]]]])  # (m=1, S=2, k=1, A=2); dim 1 categorical
    chunk = weighted_chunk(cands, th.tensor([[0.25, 0.75]]), {1: 2})
    assert chunk.tolist() == [[[0.75, 1.0]]]


def test_select_candidates_mean_sample_and_elite_by_hand():
    cands = th.tensor([[[[0.0]], [[1.0]], [[4.0]]]])  # (1, 3, 1, 1)
    q = th.tensor([[[3.0, 1.0, 2.0]], [[3.0, 1.0, 0.0]]])  # min_j Q = 3, 1, 0
    assert select_candidates("mean", cands, None, 1).item() == pytest.approx(5 / 3)
    assert select_candidates("sample", cands, None, 1).item() == 0.0
    assert select_candidates("elite", cands, q, 2).item() == pytest.approx(0.5)  # candidates 0 and 1
    with pytest.raises(ValueError, match="q_values are needed"):
        select_candidates("uncertainty", cands, None, 1)


def test_uncertainty_exploration_draws_candidates_with_the_selection_weights():
    from sb3_ua2c.exploration import UncertaintyExploration

    cands = th.tensor([[[[0.0]], [[1.0]], [[2.0]], [[3.0]]]])  # (1, 4, 1, 1)
    spread = th.tensor([0.0, 1.0, 2.0, 3.0])
    agree = th.stack([spread * 10, spread * 10 + 0.1])[:, None]
    unsure = th.stack([spread * 0.1, spread * 0.1 + 10.0])[:, None]
    th.manual_seed(0)
    assert {UncertaintyExploration().select(cands, agree, 1, {}).item() for _ in range(50)} == {3.0}
    picks = [UncertaintyExploration().select(cands, unsure, 1, {}).item() for _ in range(400)]
    assert set(picks) == {0.0, 1.0, 2.0, 3.0} and abs(np.mean(picks) - 1.5) < 0.2  # the mean: predict's chunk


def test_learn_explores_with_the_uncertainty_weights():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, exploration="uncertainty",
                 policy_kwargs={**FAST["policy_kwargs"], "selection": "uncertainty"},
                 **{k: v for k, v in FAST.items() if k != "policy_kwargs"})
    model.learn(80)
    assert model.num_timesteps == 80 and model.policy.selection == "uncertainty"


# ------------------------------------------------------------------------------ executions, by hand
class ConstantPlanner:
    """Plans the chunk ``[v, v, v]`` with ``v`` = 1, 4, 7, ... at successive calls."""

    def __init__(self) -> None:
        self.value = -2.0

    def __call__(self, obs_h, act_h):
        self.value += 3.0
        m = obs_h.shape[0]
        return PlanResult(np.full((m, 3, 1), self.value, np.float32), np.ones(m, np.int64), np.zeros((m, 3), np.float32))


@pytest.mark.parametrize(("decay", "expected"), [
    (0.0, [1.0, 2.5, 4.0, 7.0]),  # the plain mean of 1, (1, 4), (1, 4, 7), then (4, 7, 10)
    # each chunk one step older weighs twice: (2·1 + 4) / 3, (4·1 + 2·4 + 7) / 7, (4·4 + 2·7 + 10) / 7
    (math.log(2.0), [1.0, 2.0, 19 / 7, 40 / 7]),
])
def test_temporal_ensemble_by_hand(decay, expected):
    ex = AdaptiveChunkExecutor(n_envs=1, obs_dim=1, action_dim=1, chunk_size=3, history_len=1)
    planner, actions = ConstantPlanner(), []
    for t in range(4):
        step = ex.act(np.zeros((1, 1)), np.array([t == 0]), planner, ensemble_decay=decay)
        actions.append(float(step.actions[0, 0]))
    assert actions == pytest.approx(expected, rel=1e-6)


def test_temporal_ensemble_averages_only_the_given_dims():
    ex = AdaptiveChunkExecutor(n_envs=1, obs_dim=1, action_dim=2, chunk_size=2, history_len=1)

    values = iter([[0.0, -0.9], [1.0, 0.0]])

    def planner(obs_h, act_h):
        v = next(values)
        return PlanResult(np.full((1, 2, 2), v, np.float32), np.ones(1, np.int64), np.zeros((1, 2), np.float32))

    ex.act(np.zeros((1, 1)), np.array([True]), planner, ensemble_decay=0.0, ensemble_dims=[0])
    step = ex.act(np.zeros((1, 1)), np.array([False]), planner, ensemble_decay=0.0, ensemble_dims=[0])
    assert step.actions.tolist() == [[0.5, 0.0]]  # dim 0 averaged, dim 1 (categorical) the new chunk's


def test_temporal_ensemble_restarts_with_the_episode():
    ex = AdaptiveChunkExecutor(n_envs=1, obs_dim=1, action_dim=1, chunk_size=3, history_len=1)
    planner = ConstantPlanner()
    ex.act(np.zeros((1, 1)), np.array([True]), planner, ensemble_decay=0.0)
    step = ex.act(np.zeros((1, 1)), np.array([True]), planner, ensemble_decay=0.0)
    assert step.actions[0, 0] == 4.0 and ex.ensemble_weight.tolist() == [[1.0, 1.0, 1.0]]


def test_execution_rules_replan_and_ensemble_check_their_fields():
    assert ExecutionRule("ensemble").ensemble_decay == 0.01
    with pytest.raises(ValueError, match="ensemble_decay must be a finite number >= 0"):
        ExecutionRule("ensemble", ensemble_decay=-1.0)
    with pytest.raises(ValueError, match="ensemble_decay applies to execution_rule='ensemble' only"):
        ExecutionRule("replan", ensemble_decay=0.5)
    with pytest.raises(ValueError, match="execution_rule='replan'"):
        ExecutionRule(entropy_threshold=-math.inf)


@pytest.mark.parametrize("rule", ["replan", "ensemble"])
def test_policy_replans_every_step_under_replan_and_ensemble(rule):
    policy = tiny_policy(execution=ExecutionRule(rule))
    assert policy.plan_lengths(th.randn(5, 3)).tolist() == [1] * 5
    assert policy.ensemble_decay == (0.01 if rule == "ensemble" else None)


# ------------------------------------------------------------------------------ the policy and the model
def test_selection_is_checked_by_name():
    with pytest.raises(ValueError, match="selection"):
        tiny_policy(selection="median")
    with pytest.raises(ValueError, match="n_critics >= 2"):
        tiny_policy(selection="uncertainty", n_critics=1)


def test_critic_free_selections_never_call_the_critics():
    policy = tiny_policy(selection="mean")

    def refuse(*args, **kwargs):
        raise AssertionError("the critics were called")

    policy.critic.forward = refuse
    obs, act = th.zeros(2, 2, 3), th.zeros(2, 2, 2)
    for selection in ("mean", "sample", "zero_noise"):
        policy._set_selection(selection)
        chunks, lengths, _ = policy.plan_tensors(obs, act)
        assert chunks.shape == (2, 3, 2) and chunks.abs().max() <= 1.0


def test_zero_noise_selection_is_the_flow_from_zero_whatever_the_noise():
    policy = tiny_policy(selection="zero_noise")
    obs, act = th.randn(1, 2, 3), th.zeros(1, 2, 2)
    first, _, _ = policy.plan_tensors(obs, act)
    second, _, _ = policy.plan_tensors(obs, act)
    direct = policy.sample_chunks(obs, act, 1, policy.flow_steps, x0=th.zeros(1, 1, 3, 2))[:, 0].clamp(-1, 1)
    assert th.equal(first, second) and th.equal(first, direct)


def test_selection_and_rule_survive_save_load_and_act_alike(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, history_len=2,
                 execution_rule=ExecutionRule("ensemble", ensemble_decay=0.1), **FAST)
    model.set_selection("uncertainty")
    model.save(tmp_path / "m")
    loaded = UA2C.load(tmp_path / "m")
    assert loaded.policy.selection == "uncertainty" and loaded.execution == ExecutionRule("ensemble", ensemble_decay=0.1)
    np.testing.assert_array_equal(rollout_actions(model), rollout_actions(loaded))
    model.policy.save(str(tmp_path / "p.pth"))
    policy_only = type(model.policy).load(str(tmp_path / "p.pth"))
    np.testing.assert_array_equal(rollout_actions(model), rollout_actions(policy_only))
    assert UA2C.load(tmp_path / "m", selection="mean").policy.selection == "mean"
