"""Peer arms of the head-to-head (experiments.peers): zoo hyperparameters, offline data in SB3 and
d3rlpy buffers, the d3rlpy policy adapter, and one tiny unit per arm on MixedTraffic-v0."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from extras import require
from gymnasium import spaces

from envs.collection import collect_dataset
from envs.evaluation import evaluate
from experiments.peers import run_d3rlpy, run_sb3_offline_mix, run_sb3_online, zoo_hyperparams
from experiments.peers.common import ArmInputs, episode_transitions, literal_call, recorded_path
from experiments.peers.sb3_arms import OfflineMixReplayBuffer, scale_actions
from sb3_ua2c.offline import Episode

ACTION_SPACE = spaces.Box(np.array([-4.5, -1.0], np.float32), np.array([3.0, 1.0], np.float32))
OBS_SPACE = spaces.Box(-1.0, 1.0, (3,), np.float32)
TINY = {"learning_starts": 10, "batch_size": 8, "policy_kwargs": {"net_arch": [16]}}


def _episode(start: float, steps: int, terminated: bool) -> Episode:
    obs = start + np.arange(steps + 1, dtype=np.float32)[:, None] * np.ones((1, 3), np.float32) / 100
    term = np.zeros(steps, bool)
    term[-1] = terminated
    return Episode(observations=obs, actions=np.tile(np.float32([3.0, 0.0]), (steps, 1)),
                   rewards=np.arange(steps, dtype=float), terminations=term, truncations=~term & (np.arange(steps) == steps - 1))


def test_zoo_hyperparams_read_the_mixed_traffic_entries():
    assert zoo_hyperparams("sac") == {
        "learning_rate": 3e-4, "buffer_size": 100000, "learning_starts": 1000, "batch_size": 256,
        "gamma": 0.99, "tau": 0.005, "policy_kwargs": {"net_arch": [256, 256]},
    }
    tqc = zoo_hyperparams("tqc")
    assert tqc["top_quantiles_to_drop_per_net"] == 2
    assert tqc["policy_kwargs"] == {"net_arch": [256, 256], "n_critics": 2, "n_quantiles": 25}
    with pytest.raises(ValueError, match="no entry for 'Nope-v0'"):
        zoo_hyperparams("sac", "Nope-v0")
    with pytest.raises(FileNotFoundError, match="conf_file"):
        zoo_hyperparams("ppo")


def test_literal_call_reads_dicts_without_eval():
    assert literal_call("dict(net_arch=[64, 64], n_critics=2, inner=dict(a=(1, 2)))") == {
        "net_arch": [64, 64], "n_critics": 2, "inner": {"a": (1, 2)}}
    with pytest.raises(ValueError, match="only literals"):
        literal_call("__import__('os').getcwd()")


def test_episode_transitions_keep_next_observations_and_terminations():
    t = episode_transitions([_episode(0.0, 2, terminated=True), _episode(1.0, 3, terminated=False)])
    assert t["observations"].shape == (5, 3) and t["actions"].shape == (5, 2)
    np.testing.assert_allclose(t["next_observations"][:, 0], [0.01, 0.02, 1.01, 1.02, 1.03], rtol=1e-6)
    assert t["terminations"].tolist() == [False, True, False, False, False]  # the truncation bootstraps
    assert t["rewards"].tolist() == [0, 1, 0, 1, 2]


def test_records_name_paths_inside_the_working_directory_relative_to_it(tmp_path, monkeypatch):
    # committed records (results/peers_raw) must not name a directory of the machine that made them
    (tmp_path / "run").mkdir()
    monkeypatch.chdir(tmp_path / "run")
    assert recorded_path(tmp_path / "run" / "results" / "peers_work" / "seed0" / "dataset") == "results/peers_work/seed0/dataset"
    assert recorded_path("results/x") == "results/x"
    assert recorded_path(tmp_path / "elsewhere") == str(tmp_path / "elsewhere")


def test_scale_actions_maps_the_bounds_to_unit_range():
    np.testing.assert_allclose(scale_actions(np.array([[-4.5, -1.0], [3.0, 1.0], [-0.75, 0.5]]), ACTION_SPACE),
                               [[-1, -1], [1, 1], [0, 0.5]], atol=1e-7)


def test_offline_mix_buffer_draws_half_of_each_batch_offline():
    buf = OfflineMixReplayBuffer(100, OBS_SPACE, ACTION_SPACE, device="cpu", offline_ratio=0.5)
    t = episode_transitions([_episode(0.0, 4, terminated=False)])
    t["rewards"] = np.full(4, 7.0, np.float32)  # offline rows carry reward 7, online rows -1
    buf.add_offline(t)
    only_offline = buf.sample(6)  # online part empty: the whole batch is offline
    assert only_offline.rewards.flatten().tolist() == [7.0] * 6
    assert th.allclose(only_offline.actions, th.tensor([[1.0, 0.0]]).expand(6, 2))  # a = (3, 0) scaled
    for _ in range(3):
        buf.add(np.zeros(3), np.zeros(3), np.zeros(2), np.array([-1.0]), np.array([False]), [{}])
    batch = buf.sample(8)
    assert batch.rewards.flatten().tolist() == [7.0] * 4 + [-1.0] * 4
    assert batch.observations.shape == (8, 3) and batch.dones.shape == (8, 1)
    buf.offline_ratio = 0.25
    assert buf.sample(8).rewards.flatten().tolist() == [7.0] * 2 + [-1.0] * 6
    with pytest.raises(ValueError, match="offline_ratio"):
        OfflineMixReplayBuffer(10, OBS_SPACE, ACTION_SPACE, offline_ratio=1.5)
    with pytest.raises(RuntimeError, match="add_offline"):
        OfflineMixReplayBuffer(10, OBS_SPACE, ACTION_SPACE).sample(2)


def test_d3rlpy_episodes_keep_every_transition():
    require("d3rlpy")
    from d3rlpy.dataset import BasicTransitionPicker

    from experiments.peers.d3rlpy_arms import d3rlpy_episodes

    truncated, terminated = d3rlpy_episodes([_episode(0.0, 3, terminated=False), _episode(1.0, 2, terminated=True)])
    assert truncated.transition_count == 3 and terminated.transition_count == 2
    last = BasicTransitionPicker()(truncated, 2)  # bootstraps from the final observation o_3
    np.testing.assert_allclose(last.next_observation, [0.03] * 3, rtol=1e-6)
    assert last.terminal == 0.0 and last.reward.item() == 2.0
    end = BasicTransitionPicker()(terminated, 1)
    assert end.terminal == 1.0 and end.reward.item() == 1.0 and not end.next_observation.any()


def test_d3rlpy_policy_adapter_has_sb3_predict():
    from experiments.peers.d3rlpy_arms import D3rlpyPolicy

    class Fixed:
        def predict(self, x):
            return np.tile([5.0, 0.5], (len(x), 1))  # outside the acceleration bound: clipped to 3

        def sample_action(self, x):
            return np.tile([-1.0, 0.0], (len(x), 1))

    policy = D3rlpyPolicy(Fixed(), OBS_SPACE, ACTION_SPACE)
    action, state = policy.predict(np.zeros(3), state=None, episode_start=np.ones(1, bool))
    assert state is None and action.dtype == np.float32 and action.tolist() == [3.0, 0.5]
    assert policy.predict(np.zeros((2, 3)), deterministic=False)[0].tolist() == [[-1.0, 0.0]] * 2


def test_best_of_n_acts_by_the_critics_best_sample_per_observation():
    from experiments.peers.d3rlpy_arms import BestOfNPolicy

    class Sampler:  # the samples of one observation are 0.1 * (0, 1, 2, 3); the critic likes -|a - target|
        def sample_action(self, x):
            return np.stack([0.1 * (np.arange(len(x)) % 4), np.zeros(len(x))], axis=1)

        def predict_value(self, x, action):
            target = x[:, 0]  # observation 0 wants 0.2, observation 1 wants 0.3
            return -np.abs(action[:, 0] - target)

    policy = BestOfNPolicy(Sampler(), OBS_SPACE, ACTION_SPACE, n=4)
    obs = np.array([[0.2, 0.0, 0.0], [0.3, 0.0, 0.0]], dtype=np.float32)
    actions, _ = policy.predict(obs)
    np.testing.assert_allclose(actions, [[0.2, 0.0], [0.3, 0.0]], atol=1e-6)
    np.testing.assert_allclose(policy.predict(obs[1])[0], [0.3, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="best_of_n"):
        BestOfNPolicy(Sampler(), OBS_SPACE, ACTION_SPACE, n=0)


class ConstantPolicy:
    """A policy with SB3's predict that always brakes gently."""

    observation_space = spaces.Box(-np.inf, np.inf, (20,), np.float32)

    def __init__(self, action_space):
        self.action_space = action_space

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.float32([-0.5, 0.0]), None


def test_evaluate_serves_any_policy_with_predict(make_env):
    env = make_env(time_limit=2.0)
    env.reset(seed=1000 * 7 + 1)
    total = 0.0
    for _ in range(10):
        total += float(env.step(np.float32([-0.5, 0.0]))[1])
    env.close()
    policy = ConstantPolicy(env.action_space)
    policy.observation_space = env.observation_space
    episodes = evaluate(policy, n_episodes=2, seeds=(7,), env_settings_={"env_kwargs": {"time_limit": 2.0}})
    assert [e.seed for e in episodes] == [7000, 7001]
    assert episodes[1].reward == pytest.approx(total, abs=1e-9) and episodes[1].length == 10
    assert episodes[0].mean_executed_length == 1.0
    with pytest.raises(ValueError, match=r"\['entropy_threshold'\] apply to UA2C only"):
        evaluate(policy, seeds=(7,), entropy_threshold=0.5, env_settings_={"env_kwargs": {"time_limit": 2.0}})
    with pytest.raises(TypeError, match="checkpoint"):
        evaluate(42, env_settings_={"env_kwargs": {"time_limit": 2.0}})


def test_arm_inputs_reject_a_bad_evaluation_protocol():
    # an arm unit's inputs refuse a bad protocol when they are made, before any training
    def inputs(seeds, episodes):
        return ArmInputs("out", "data", seed=1, online_steps=5, eval_seeds=seeds, eval_episodes=episodes)

    assert inputs([3, 4], 2).eval_seeds == (3, 4)
    with pytest.raises(ValueError, match="eval_seeds"):
        inputs((), 2)
    with pytest.raises(ValueError, match="eval_episodes"):
        inputs((1,), 0)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    return collect_dataset(tmp_path_factory.mktemp("peers") / "ds", 2, env_kwargs={"time_limit": 2.0}, seed=5)


def _check_record(record, arm, dataset, online_steps=30):
    assert record["arm"] == arm and record["seed"] == 1 and record["online_steps"] == online_steps
    assert record["dataset"]["transitions"] == 20 and record["env"]["env_kwargs"] == {"time_limit": 2.0}
    assert [e["end_step"] for e in record["online_episodes"]] == [10, 20, 30]  # 2-s episodes of 10 steps
    episodes = record["evaluation"]["episodes"]
    assert [e["seed"] for e in episodes] == [2001000, 2001001] and record["evaluation"]["summary"]["episodes"] == 2
    assert episodes[0]["jerk_per_step"] == pytest.approx(episodes[0]["cumulative_jerk"] / 10)
    assert record["wall_seconds"]["total"] == pytest.approx(sum(v for k, v in record["wall_seconds"].items() if k != "total"))


@pytest.mark.parametrize("algo", ["sac", "tqc"])
def test_sb3_online_unit(tiny_dataset, tmp_path, algo):
    inputs = ArmInputs(tmp_path, tiny_dataset.path, seed=1, online_steps=30, eval_seeds=(2001,), eval_episodes=2)
    record = run_sb3_online(inputs, algo=algo, hyperparams=TINY)
    _check_record(record, algo, tiny_dataset)
    assert record["hyperparams"]["learning_rate"] == 3e-4 and record["hyperparams"]["policy_kwargs"] == {"net_arch": [16]}
    assert record["offline_evaluation"] is None and (tmp_path / "model.zip").is_file()


def test_sb3_offline_mix_unit_is_reproducible(tiny_dataset, tmp_path):
    kwargs = dict(dataset=tiny_dataset.path, seed=1, online_steps=30, eval_seeds=(2001,), eval_episodes=2)
    first = run_sb3_offline_mix(ArmInputs(tmp_path / "a", **kwargs), hyperparams=TINY)
    _check_record(first, "sac_offline_mix", tiny_dataset)
    assert first["hyperparams"]["offline_ratio"] == 0.5 and "LayerNorm" in first["notes"]
    again = run_sb3_offline_mix(ArmInputs(tmp_path / "b", **kwargs), hyperparams=TINY)
    assert again["evaluation"] == first["evaluation"] and again["online_episodes"] == first["online_episodes"]
    with pytest.raises(ValueError, match="online_steps"):
        run_sb3_offline_mix(ArmInputs(tmp_path / "c", **{**kwargs, "online_steps": 0}), hyperparams=TINY)


@pytest.mark.parametrize("algo", ["iql", "calql"])
def test_d3rlpy_unit_offline_then_online(tiny_dataset, tmp_path, monkeypatch, algo):
    require("d3rlpy")
    monkeypatch.chdir(tmp_path)
    inputs = dict(dataset=tiny_dataset.path, seed=1, online_steps=30, eval_seeds=(2001,), eval_episodes=2)
    record = run_d3rlpy(ArmInputs(tmp_path / "unit", **inputs), algo=algo, offline_steps=5, batch_size=8)
    _check_record(record, algo, tiny_dataset)
    assert record["offline_steps"] == 5 and record["offline_evaluation"]["summary"]["episodes"] == 2
    assert record["hyperparams"]["config"]["action_scaler"]["params"] == {"minimum": [-4.5, -1.0], "maximum": [3.0, 1.0]}
    assert (tmp_path / "unit" / "d3rlpy" / "online" / "model_30.d3").is_file()
    assert not (tmp_path / "d3rlpy_logs").exists()
    with pytest.raises(ValueError, match="algo must be one of"):
        run_d3rlpy(ArmInputs(tmp_path / "x", tiny_dataset.path, 1, 30, (2001,), 2), algo="cql")
    if algo == "iql":  # seeded: the same unit gives the same record
        again = run_d3rlpy(ArmInputs(tmp_path / "again", **inputs), algo=algo, offline_steps=5, batch_size=8)
        assert again["evaluation"] == record["evaluation"] and again["online_episodes"] == record["online_episodes"]
        assert again["offline_evaluation"] == record["offline_evaluation"]
