"""Execution (Eq. 7): the adaptive-chunk executor, the rule with a numeric δ and with
``entropy_threshold="auto"`` (δ set for a target mean ``L_t``)."""

import math

import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import ACT, FAST, OBS, rollout_actions

from sb3_ua2c import UA2C
from sb3_ua2c.chunking import (
    auto_entropy_threshold,
    chunk_entropy,
    executable_prefix_length,
)
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.execution import AUTO_THRESHOLD_WINDOW, AdaptiveChunkExecutor, EntropyWindow, PlanResult
from sb3_ua2c.policies import UA2CPolicy

T = th.tensor


# ------------------------------------------------------------------------------ the executor
class ScriptedPlanner:
    """Returns chunks whose entries encode the plan number; records the histories it saw."""

    def __init__(self, k: int, lengths: list[int]):
        self.k, self.lengths, self.calls = k, list(lengths), []

    def __call__(self, obs_h: np.ndarray, act_h: np.ndarray) -> PlanResult:
        m = obs_h.shape[0]
        self.calls.append((obs_h.copy(), act_h.copy()))
        n = len(self.calls)
        chunks = (10 * n + np.arange(self.k, dtype=np.float32)).reshape(1, self.k, 1).repeat(m, 0) / 100
        lengths = np.array([self.lengths.pop(0) for _ in range(m)])
        return PlanResult(chunks, lengths, np.zeros((m, self.k), dtype=np.float32))


def test_executor_replans_after_the_prefix_and_pads_history():
    ex = AdaptiveChunkExecutor(n_envs=1, obs_dim=1, action_dim=1, chunk_size=3, history_len=2)
    planner = ScriptedPlanner(3, [2, 3])
    obs = [np.array([[float(i)]]) for i in range(6)]
    acts, new = [], []
    for t in range(4):
        step = ex.act(obs[t], np.array([t == 0]), planner)
        acts.append(step.actions.item())
        new.append(bool(step.new_plan[0]))
    # plan 1 (L=2) plays 0.10, 0.11; plan 2 (L=3) starts at t=2
    assert acts == pytest.approx([0.10, 0.11, 0.20, 0.21])
    assert new == [True, False, True, False]
    # first plan: history padded with o_0 and zero actions
    assert planner.calls[0][0].ravel().tolist() == [0.0, 0.0]
    assert planner.calls[0][1].ravel().tolist() == [0.0, 0.0]
    # second plan at t=2: o_1, o_2 and a_0, a_1
    assert planner.calls[1][0].ravel().tolist() == [1.0, 2.0]
    assert planner.calls[1][1].ravel().tolist() == pytest.approx([0.10, 0.11])


def test_executor_replans_at_episode_start_and_state_round_trip():
    ex = AdaptiveChunkExecutor(n_envs=2, obs_dim=1, action_dim=1, chunk_size=3, history_len=2)
    planner = ScriptedPlanner(3, [3, 3, 3])
    ex.act(np.array([[1.0], [2.0]]), np.array([True, True]), planner)
    state = ex.state
    # env 1 starts a new episode: only it replans, its history restarts from the new observation
    step = ex.act(np.array([[3.0], [4.0]]), np.array([False, True]), planner)
    assert step.new_plan.tolist() == [False, True]
    assert planner.calls[-1][0].ravel().tolist() == [4.0, 4.0]
    assert step.actions.ravel().tolist() == pytest.approx([0.11, 0.20])
    # a copy rebuilt from the saved state behaves identically
    other = AdaptiveChunkExecutor(n_envs=2, obs_dim=1, action_dim=1, chunk_size=3, history_len=2)
    other.load_state(state)
    again = other.act(np.array([[3.0], [4.0]]), np.array([False, True]), ScriptedPlanner(3, [3]))
    assert again.actions[0, 0] == pytest.approx(0.11)
    with pytest.raises(ValueError, match="plan has shape"):
        other.load_state((state[0], state[1], np.zeros((2, 4, 1)), state[3], state[4], state[5]))
    with pytest.raises(ValueError, match="6 arrays"):
        other.load_state(state[:5])


def test_executor_noise_is_clipped_and_recorded_in_history():
    ex = AdaptiveChunkExecutor(n_envs=1, obs_dim=1, action_dim=1, chunk_size=2, history_len=1)
    step = ex.act(np.zeros((1, 1)), np.array([True]), ScriptedPlanner(2, [2]), noise=np.array([[5.0]]))
    assert step.actions.item() == 1.0
    assert ex.action_history.item() == 1.0


# ------------------------------------------------------------------------------ "auto": δ from a window
# running maxima M_u = max(H_1..H_u): row 1 [0.1, 0.3, 0.35], row 2 [-0.5, 0.4, 0.6], row 3 [0, 0, 0.7];
# the pooled M_u, u >= 2, sorted: [0.0, 0.3, 0.35, 0.4, 0.6, 0.7]; mean L_t(δ) = 1 + #{M_u <= δ} / 3
WINDOW = T([[0.1, 0.3, 0.35], [-0.5, 0.4, 0.6], [0.0, -1.0, 0.7]])


@pytest.mark.parametrize(
    ("target", "delta", "lengths"),
    [
        (1.0, -math.inf, [1, 1, 1]),  # one action per plan
        (4 / 3, 0.0, [1, 1, 2]),  # c = 1: the smallest maximum
        (5 / 3, 0.3, [2, 1, 2]),  # c = 2
        (2.0, 0.35, [3, 1, 2]),  # c = 3
        (2.1, 0.4, [3, 2, 2]),  # c = ceil(3.3) = 4: the first mean >= 2.1 is 7/3
        (7 / 3, 0.4, [3, 2, 2]),  # c = 4
        (3.0, 0.7, [3, 3, 3]),  # c = 6: the largest maximum
    ],
)
def test_auto_entropy_threshold_hand_computed(target, delta, lengths):
    got = auto_entropy_threshold(WINDOW, target)
    assert got.shape == () and got.item() == pytest.approx(delta)
    assert executable_prefix_length(WINDOW, got.item()).tolist() == lengths
    # it is the smallest such δ: just below it, the mean L_t falls under the target
    if math.isfinite(delta):
        below = np.nextafter(np.float32(got.item()), np.float32(-np.inf)).item()
        assert executable_prefix_length(WINDOW, below).float().mean().item() < target


def test_auto_entropy_threshold_ties_and_nan():
    # running maxima [-1, 0, 0] and [0.5, 0.5, 0.5]: pooled u >= 2 sorted [0, 0, 0.5, 0.5]
    rows = T([[-1.0, 0.0, -2.0], [0.5, -3.0, -3.0]])
    assert auto_entropy_threshold(rows, 2.0).item() == 0.0  # mean L_t = (3 + 1) / 2 = 2
    assert auto_entropy_threshold(rows, 1.5).item() == 0.0  # c = 1, but the tie gives mean 2 >= 1.5
    # a NaN entropy is unreliable (+inf): L_t = k needs δ = inf, and even then the NaN stops the prefix
    nan_rows = T([[0.0, math.nan, -1.0], [0.0, 0.0, 0.0]])
    assert auto_entropy_threshold(nan_rows, 2.0).item() == 0.0
    assert auto_entropy_threshold(nan_rows, 3.0).item() == math.inf
    # a leading batch dim: one δ per group, here per row (row 2 alone: c = 1 -> M_2 = 0.5)
    per_row = auto_entropy_threshold(rows.unsqueeze(1), 2.0)
    assert per_row.tolist() == [0.0, 0.5]


def test_entropy_window_is_a_ring_of_the_last_rows():
    window = EntropyWindow(chunk_size=2, size=3)
    window.add(T([[1.0, 1.0], [2.0, 2.0]]))
    assert int(window.count) == 2 and window.rows[:2].tolist() == [[1.0, 1.0], [2.0, 2.0]]
    window.add(T([[3.0, 3.0], [4.0, 4.0]]))  # 4 overwrites the oldest row
    assert int(window.count) == 4 and window.rows.tolist() == [[4.0, 4.0], [2.0, 2.0], [3.0, 3.0]]
    window.add(T([[5.0, 5.0], [6.0, 6.0], [7.0, 7.0], [8.0, 8.0]]))  # more rows than the ring holds
    assert int(window.count) == 8 and sorted(window.rows[:, 0].tolist()) == [6.0, 7.0, 8.0]
    assert set(window.state_dict()) == {"rows", "count"}


# ------------------------------------------------------------------------------ Eq. 7 in a replanning
# S = 3 fixed candidates, k = 3, one action dim; the critics rank them c1 > c0 > c2 (fake min_j Q_j)
CANDIDATES = T([[0.5, -0.2, 0.4], [0.9, -0.3, 0.0], [0.0, 0.6, 0.25]]).reshape(1, 3, 3, 1)


class _FirstActionCritic(nn.Module):
    def forward(self, obs_history, chunks):  # (m, C, k, 1) -> (2, m, C): Q = a_0 and a_0 + 1
        q = chunks[..., 0, 0]
        return th.stack([q, q + 1.0])


def fixed_policy(**rule):
    """k = 3, S = 3 fixed candidates, acting by the best of them under ``ExecutionRule(**rule)``."""
    policy = UA2CPolicy(
        OBS, ACT, lambda _: 1e-3, chunk_size=3, history_len=2, flow_steps=10, n_candidates=3, n_elite=1,
        execution=ExecutionRule(**rule),
    )
    policy.sample_chunks = lambda *args, **kw: CANDIDATES.clone()
    policy.critic = _FirstActionCritic()
    return policy


def replan(policy, record=False):
    with th.no_grad():
        chunks, lengths, entropy = policy.plan_tensors(th.zeros(1, 2, 1), th.zeros(1, 2, 1), record_entropy=record)
    return chunks[0, :, 0], lengths.item(), entropy


@pytest.mark.parametrize(("delta", "length"), [(-10.0, 1), (math.inf, 3)])
def test_the_best_candidate_runs_for_its_prefix_length(delta, length):
    chunks, lengths, _ = replan(fixed_policy(entropy_threshold=delta))
    assert chunks.tolist() == pytest.approx([0.9, -0.3, 0.0])  # c1: the highest min_j Q_j
    assert lengths == length


def test_entropy_rule_is_eq7_on_the_candidates_entropies():
    entropy = chunk_entropy(CANDIDATES, discrete=True)[0]  # (k,)
    # unbiased variances 0.2033, 0.2433, 0.0408 -> H_u = ½ log(2πe σ²) = 0.6225, 0.7122, -0.1802;
    # running maxima 0.6225, 0.7122, 0.7122: L_t = 1 below 0.7122, 3 from it on
    assert entropy.tolist() == pytest.approx([0.6225, 0.7122, -0.1802], abs=1e-4)
    for delta, length in [(0.5, 1), (0.65, 1), (0.7, 1), (0.72, 3), (math.inf, 3)]:
        assert replan(fixed_policy(entropy_threshold=delta))[1] == length


# ------------------------------------------------------------------------------ "auto" in a replanning
def test_auto_threshold_reads_and_records_the_window():
    policy = fixed_policy(entropy_threshold="auto", target_plan_length=2.0)
    h = chunk_entropy(CANDIDATES, discrete=True)[0]  # [0.623, 0.712, -0.198]: running maxima [0.623, 0.712, 0.712]
    # empty window: the plan gets its own δ, the shortest L_t >= 2 its entropies allow (M_2 = M_3: 3)
    assert math.isnan(policy.current_entropy_threshold())
    assert replan(policy)[1] == 3
    assert int(policy.entropy_window.count) == 0  # not recorded without record_entropy
    policy.entropy_window.add(WINDOW)  # δ = 0.35 for a mean of 2 (see above)
    assert policy.current_entropy_threshold().item() == pytest.approx(0.35)
    assert replan(policy, record=True)[1] == 1  # H_1 = 0.623 > 0.35
    assert int(policy.entropy_window.count) == 4
    assert th.equal(policy.entropy_window.rows[3], h)
    # the new row's maxima [0.712, 0.712] join the pool: [0, 0.3, 0.35, 0.4, 0.6, 0.7, 0.712, 0.712]
    # c = ceil(4 * (2 - 1)) = 4 -> δ = 0.4
    assert policy.current_entropy_threshold().item() == pytest.approx(0.4)


def test_target_plan_length_defaults_to_the_middle_of_1_and_k():
    policy = fixed_policy(entropy_threshold="auto")
    assert policy.execution.target_plan_length is None
    policy.entropy_window.add(WINDOW)
    assert policy.current_entropy_threshold().item() == pytest.approx(0.35)  # target (3 + 1) / 2 = 2


# ------------------------------------------------------------------------------ with UA2C
def weights(model):
    return {k: v.clone() for k, v in model.policy.state_dict().items()}



def test_auto_threshold_in_training_and_save_load(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, entropy_threshold="auto", target_plan_length=2.5, **FAST)
    model.learn(200)
    window = model.policy.entropy_window
    n_plans = len(model._plan_lengths)  # the policy's plans after the warm-up, one row each
    assert int(window.count) == n_plans > 0
    # the δ now in force gives the window's plans a mean L_t of at least 2.5, and just below it less
    rows = window.rows[: min(n_plans, AUTO_THRESHOLD_WINDOW)]
    delta = model.policy.current_entropy_threshold().item()
    assert executable_prefix_length(rows, delta).float().mean().item() >= 2.5
    below = np.nextafter(np.float32(delta), np.float32(-np.inf)).item()
    assert executable_prefix_length(rows, below).float().mean().item() < 2.5
    # predict, deterministic or not, reads δ and never changes the window
    before = rollout_actions(model)
    rollout_actions(model, deterministic=False)
    assert int(window.count) == n_plans
    np.testing.assert_array_equal(rollout_actions(model), before)
    model.save(tmp_path / "auto.zip")
    loaded = UA2C.load(tmp_path / "auto.zip")
    assert loaded.execution == loaded.policy.execution == ExecutionRule(entropy_threshold="auto", target_plan_length=2.5)
    assert th.equal(loaded.policy.entropy_window.rows, window.rows)
    assert loaded.policy.current_entropy_threshold().item() == delta
    np.testing.assert_array_equal(rollout_actions(loaded), before)
    # the policy alone keeps the window too
    model.policy.save(tmp_path / "policy.pt")
    policy = UA2CPolicy.load(tmp_path / "policy.pt")
    assert policy.current_entropy_threshold().item() == delta
    np.testing.assert_array_equal(rollout_actions(policy), before)
    # a numeric δ at load time drops the window (a target without "auto" is refused)
    with pytest.raises(ValueError, match="target_plan_length"):
        UA2C.load(tmp_path / "auto.zip", entropy_threshold=0.0)
    plain = UA2C.load(tmp_path / "auto.zip", entropy_threshold=0.0, target_plan_length=None)
    assert plain.policy.entropy_window is None and "entropy_window.rows" not in plain.policy.state_dict()


def test_auto_threshold_runs_are_bit_identical():
    runs = [
        UA2C("MlpPolicy", "Pendulum-v1", seed=4, entropy_threshold="auto", **FAST).learn(150) for _ in range(2)
    ]
    for key, value in weights(runs[0]).items():
        assert th.equal(value, runs[1].policy.state_dict()[key]), key
    assert int(runs[0].policy.entropy_window.count) > 0


def test_auto_override_of_a_numeric_checkpoint_starts_with_an_empty_window(tmp_path):
    UA2C("MlpPolicy", "Pendulum-v1", seed=0, entropy_threshold=-0.5, **FAST).save(tmp_path / "numeric.zip")
    auto = UA2C.load(tmp_path / "numeric.zip", entropy_threshold="auto", target_plan_length=1.0)
    assert int(auto.policy.entropy_window.count) == 0
    assert math.isnan(auto.policy.current_entropy_threshold())
    auto.predict(np.zeros(3, np.float32), deterministic=True)
    assert auto.policy.last_plan_lengths.tolist() == [1]  # target 1: one action per plan
    assert int(auto.policy.entropy_window.count) == 0


def test_set_execution_rule_to_auto_and_back():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    model.set_execution_rule(ExecutionRule(entropy_threshold="auto", target_plan_length=4))
    assert model.execution == model.policy.execution == ExecutionRule(entropy_threshold="auto", target_plan_length=4)
    assert model.policy.entropy_window.rows.shape == (AUTO_THRESHOLD_WINDOW, 5)
    model.set_execution_rule(ExecutionRule(entropy_threshold=math.inf))
    assert model.policy.entropy_window is None and model.policy.execution.entropy_threshold == math.inf
    with pytest.raises(ValueError, match="target_plan_length"):
        model.set_execution_rule(ExecutionRule(entropy_threshold=0.0, target_plan_length=2))


# ------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(entropy_threshold="Auto"), "entropy_threshold must be a number or 'auto'"),
        (dict(entropy_threshold=None), "entropy_threshold must be a number or 'auto'"),
        (dict(entropy_threshold=True), "entropy_threshold must be a number or 'auto'"),
        (dict(entropy_threshold="auto", target_plan_length=0.5), r"target_plan_length must be a number in \[1, "),
        (dict(entropy_threshold="auto", target_plan_length=6), r"target_plan_length must be a number in \[1, "),
        (dict(entropy_threshold="auto", target_plan_length="3"), "target_plan_length must be a number"),
        (dict(entropy_threshold="auto", target_plan_length=math.nan), "target_plan_length must be a number"),
        (dict(target_plan_length=3.0), "target_plan_length applies to entropy_threshold='auto' only"),
        (dict(entropy_threshold=math.inf, target_plan_length=3.0), "target_plan_length applies"),
    ],
)
def test_bad_execution_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ExecutionRule(**kwargs).check_chunk_size(5)
    if None in kwargs.values():
        return  # UA2C's None stands for the rule's default
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", "Pendulum-v1", **kwargs)  # chunk_size 5


def test_a_target_longer_than_the_chunk_is_refused_by_the_policy():
    long = ExecutionRule(entropy_threshold="auto", target_plan_length=3.5)  # a number in [1, inf): valid alone
    with pytest.raises(ValueError, match=r"target_plan_length must be a number in \[1, chunk_size=3\], got 3.5"):
        fixed_policy(entropy_threshold="auto", target_plan_length=3.5)
    policy = fixed_policy(entropy_threshold="auto", target_plan_length=3)
    with pytest.raises(ValueError, match="chunk_size=3"):
        policy._set_execution_rule(long)
    assert policy.execution.target_plan_length == 3  # unchanged by the refused rule


def test_execution_arguments_are_kept_as_given():
    model = UA2C("MlpPolicy", "Pendulum-v1", entropy_threshold="auto", target_plan_length=3, **FAST)
    assert model.execution.target_plan_length == model.policy.execution.target_plan_length == 3
    assert model.policy.current_entropy_threshold(th.zeros(1, 5)).shape == (1, 1)
    assert UA2C("MlpPolicy", "Pendulum-v1", entropy_threshold=1, **FAST).policy.current_entropy_threshold() == 1.0
