"""OGBench benchmark groundwork: locally generated play data, its single-task rewards, the SB3 env, one unit.

Needs the ``ogbench`` extra: without it the tests fail under ``CI=true`` (``.ci/run`` installs
the extra) and skip elsewhere.
"""

from __future__ import annotations

import importlib
import json
import math

import numpy as np
import pytest
from extras import require

TASK = "cube-single-play-singletask-task2-v0"
GOAL = np.array([0.50, 0.0, 0.02])  # cube-single task 2's target (ogbench CubeEnv.set_tasks)
CUBE_QPOS = slice(14, 17)  # the cube's xyz in qpos, after the arm's and gripper's 14 joints

# ogbench builds float32 Boxes from float64 bounds; our env's infinite observation bounds are OGBench's
pytestmark = pytest.mark.filterwarnings("ignore:.*precision lowered:UserWarning",
                                        "ignore:.*Box observation space m:UserWarning")


@pytest.fixture
def no_ogbench(monkeypatch):
    real = importlib.import_module

    def fake(name, *args, **kwargs):
        if name == "ogbench":
            raise ImportError("No module named 'ogbench'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", fake)


def test_missing_ogbench_fails_under_ci(monkeypatch, no_ogbench):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI must run this test: ogbench is missing"):
        require("ogbench")


def test_missing_ogbench_skips_on_a_developer_machine(monkeypatch, no_ogbench):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"ogbench is missing: pip install -e '\.\[ogbench\]'"):
        require("ogbench")


@pytest.fixture(scope="module")
def ogb():
    require("ogbench")
    import experiments.ogbench as ogb

    return ogb


@pytest.fixture(scope="module")
def tiny_dataset(ogb, tmp_path_factory):
    """Two play episodes of 30 steps (the validation file repeats them: 2 // 10 = 0 episodes)."""
    path = tmp_path_factory.mktemp("ogbench") / "cube-single-play-v0.npz"
    report = ogb.generate_play_dataset(TASK, path, n_episodes=2, episode_steps=30, seed=3)
    return path, report


# ------------------------------------------------------------------------------------ task names
def test_task_name_parts(ogb):
    name = ogb.TaskName.parse(TASK)
    assert (name.env_name, name.dataset_type, name.dataset_file) == ("cube-single-v0", "play", "cube-single-play-v0.npz")
    scene = ogb.TaskName.parse("scene-play-singletask-v0")
    assert (scene.env_name, scene.dataset_file) == ("scene-v0", "scene-play-v0.npz")


@pytest.mark.parametrize("bad", ["cube-single-v0", "antmaze-medium-navigate-singletask-v0",
                                 "cube-single-noisy-singletask-task2-v0", "singletask-v0"])
def test_task_name_rejects_what_cannot_be_generated(ogb, bad):
    with pytest.raises(ValueError, match="task"):
        ogb.TaskName.parse(bad)
    with pytest.raises(TypeError, match="task must be"):
        ogb.TaskName.parse(2)


# ------------------------------------------------------------------------------------ generation
def test_generated_file_has_ogbench_layout(tiny_dataset):
    path, report = tiny_dataset
    raw = np.load(path)
    assert set(raw.files) == {"observations", "actions", "terminals", "qpos", "qvel"}
    assert raw["observations"].shape == (60, 28) and raw["observations"].dtype == np.float32
    assert raw["actions"].shape == (60, 5) and np.abs(raw["actions"]).max() <= 1.0
    assert raw["qpos"].shape == (60, 21) and raw["terminals"].dtype == bool
    np.testing.assert_array_equal(np.flatnonzero(raw["terminals"]), [29, 59])  # the last step of each episode
    assert report["steps"] == 60 and report["bytes"] > 0
    val = np.load(str(path).replace(".npz", "-val.npz"))
    np.testing.assert_array_equal(val["observations"], raw["observations"])


def test_generation_is_seeded(ogb, tmp_path):
    a = ogb.generate_play_dataset(TASK, tmp_path / "a.npz", n_episodes=1, episode_steps=12, seed=5)
    b = ogb.generate_play_dataset(TASK, tmp_path / "b.npz", n_episodes=1, episode_steps=12, seed=5)
    c = ogb.generate_play_dataset(TASK, tmp_path / "c.npz", n_episodes=1, episode_steps=12, seed=6)
    first, second, other = (np.load(r["path"]) for r in (a, b, c))
    np.testing.assert_array_equal(first["actions"], second["actions"])
    np.testing.assert_array_equal(first["qpos"], second["qpos"])
    assert not np.allclose(first["qpos"], other["qpos"])


def test_generation_rejects_bad_arguments(ogb, tmp_path):
    with pytest.raises(ValueError, match="path must end with .npz"):
        ogb.generate_play_dataset(TASK, tmp_path / "x.h5", n_episodes=1)
    with pytest.raises(ValueError, match="n_episodes"):
        ogb.generate_play_dataset(TASK, tmp_path / "x.npz", n_episodes=0)
    with pytest.raises(ValueError, match="noise"):
        ogb.generate_play_dataset(TASK, tmp_path / "x.npz", n_episodes=1, noise=-0.1)


MAZE = "pointmaze-medium-navigate-singletask-task1-v0"


def test_navigate_data_follow_the_oracle_direction(ogb, tmp_path):
    """Without noise every pointmaze action is the unit vector to the oracle's subgoal (norm 1);
    with OGBench's noise 0.5 it is not, and the file loads with OGBench's single-task rewards."""
    exact = np.load(ogb.generate_play_dataset(MAZE, tmp_path / "a.npz", n_episodes=1, episode_steps=40, noise=0.0)["path"])
    assert exact["actions"].shape == (40, 2) and exact["qpos"].shape == (40, 2)
    np.testing.assert_allclose(np.linalg.norm(exact["actions"], axis=1), 1.0, atol=1e-4)
    np.testing.assert_array_equal(exact["observations"], exact["qpos"])  # the point's xy is its observation
    path = tmp_path / "pointmaze-medium-navigate-v0.npz"
    noisy = np.load(ogb.generate_play_dataset(MAZE, path, n_episodes=2, episode_steps=40, seed=1)["path"])
    assert np.abs(noisy["actions"]).max() <= 1.0 and np.std(np.linalg.norm(noisy["actions"], axis=1)) > 0.05
    np.testing.assert_array_equal(np.flatnonzero(noisy["terminals"]), [39, 79])
    env, train, _ = ogb.load_singletask(MAZE, path)
    env.close()
    assert set(np.unique(train["rewards"])) <= {-1.0, 0.0} and train["observations"].shape == (78, 2)
    maze = ogb.OGBenchSingleTask(MAZE)  # the maze's reset info has no qpos: it is read from the simulator
    obs, info = maze.reset(seed=0)
    maze.close()
    np.testing.assert_allclose(info["qpos"], obs, atol=1e-6)
    assert maze.max_episode_steps == 1000 and info["success"] is False


# ------------------------------------------------------------------------------------ loading
def test_round_trip_through_make_env_and_datasets(ogb, tiny_dataset):
    path, _ = tiny_dataset
    env, train, val = ogb.load_singletask(TASK, path)
    env.close()
    raw = np.load(path)
    # compact_dataset=False: each 30-step trajectory gives 29 transitions (s_t, a_t, s_t+1)
    assert train["observations"].shape == (58, 28) and train["next_observations"].shape == (58, 28)
    assert train["actions"].shape == (58, 5) and train["rewards"].shape == train["masks"].shape == (58,)
    np.testing.assert_array_equal(np.flatnonzero(train["terminals"]), [28, 57])
    keep = np.r_[0:29, 30:59]
    np.testing.assert_array_equal(train["observations"], raw["observations"][keep])
    np.testing.assert_array_equal(train["next_observations"], raw["observations"][keep + 1])
    # OGBench's single-task reward of transition (s, a, s'): success of s (cube within 4 cm of the goal) - 1
    success = np.linalg.norm(raw["qpos"][keep][:, CUBE_QPOS] - GOAL, axis=1) <= 0.04
    np.testing.assert_array_equal(train["rewards"], success - 1.0)
    np.testing.assert_array_equal(train["masks"], 1.0 - success)
    assert val["observations"].shape == (58, 28)


def _hand_made(path, cube_xyzs, ends):
    """An npz in OGBench's layout whose cube positions are set by hand (observation t = t)."""
    n = len(cube_xyzs)
    qpos = np.zeros((n, 21), dtype=np.float32)
    qpos[:, CUBE_QPOS] = cube_xyzs
    np.savez(path, observations=np.arange(n, dtype=np.float32)[:, None].repeat(28, 1),
             actions=np.zeros((n, 5), np.float32), terminals=np.asarray(ends, bool), qpos=qpos,
             qvel=np.zeros((n, 20), np.float32))
    np.savez(str(path).replace(".npz", "-val.npz"), **np.load(path))


def test_single_task_rewards_and_episode_cuts_on_hand_checked_states(ogb, tmp_path):
    far, at_goal, near, above = [0.3, 0.2, 0.02], GOAL, GOAL + [0.03, 0, 0], GOAL + [0, 0, 0.05]
    # trajectory 1: far, goal, 3 cm off (inside 4 cm), 5 cm above (outside); trajectory 2: far x3
    path = tmp_path / "hand.npz"
    _hand_made(path, [far, at_goal, near, above, far, far, far], [0, 0, 0, 1, 0, 0, 1])
    _, train, _ = ogb.load_singletask(TASK, path)
    np.testing.assert_array_equal(train["rewards"], [-1, 0, 0, -1, -1])
    np.testing.assert_array_equal(train["masks"], [1, 0, 0, 1, 1])
    np.testing.assert_array_equal(train["terminals"], [0, 0, 1, 0, 1])
    episodes = ogb.to_episodes(train)
    # cut after each solved state (terminated) and at trajectory ends (truncated)
    assert [len(e) for e in episodes] == [2, 1, 2]
    assert [(bool(e.terminations[-1]), bool(e.truncations[-1])) for e in episodes] == [
        (True, False), (True, False), (False, True)]
    np.testing.assert_array_equal(episodes[0].observations[:, 0], [0, 1, 2])
    np.testing.assert_array_equal(episodes[1].observations[:, 0], [2, 3])
    np.testing.assert_array_equal(episodes[2].observations[:, 0], [4, 5, 6])
    np.testing.assert_array_equal(episodes[0].rewards, [-1, 0])


def test_sparse_reward_is_minus_one_until_every_subtask_is_solved(ogb):
    from experiments.ogbench.data import sparse_reward

    np.testing.assert_array_equal(sparse_reward(np.array([-3.0, -1.0, 0.0])), [-1.0, -1.0, 0.0])


def test_to_episodes_rejects_a_compact_or_cut_dataset(ogb):
    with pytest.raises(ValueError, match="next_observations"):
        ogb.to_episodes({"observations": np.zeros((2, 1)), "valids": np.ones(2)})
    cut = {k: np.zeros((2, 1)) for k in ("observations", "next_observations", "actions")}
    cut.update(rewards=np.zeros(2), masks=np.ones(2), terminals=np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="terminals"):
        ogb.to_episodes(cut)


def test_missing_dataset_file_is_a_clear_error(ogb, tmp_path):
    with pytest.raises(FileNotFoundError, match="generate it first"):
        ogb.load_singletask(TASK, tmp_path / "nothing.npz")


# ------------------------------------------------------------------------------------ env
def test_env_passes_gymnasium_and_sb3_checks(ogb):
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(f"experiments.ogbench:{ogb.ENV_ID}", task=TASK)
    try:
        check_env(env.unwrapped)
        sb3_check_env(env.unwrapped)
        obs, info = env.reset(seed=0)
        assert obs.shape == (28,) and obs.dtype == np.float32 and info["success"] is False
        assert env.unwrapped.max_episode_steps == 200
    finally:
        env.close()
    with pytest.raises(TypeError, match="sparse must be a bool"):
        ogb.OGBenchSingleTask(TASK, sparse=1)
    with pytest.raises(ValueError, match="max_episode_steps"):
        ogb.OGBenchSingleTask(TASK, max_episode_steps=0)


def test_env_reward_and_success_at_the_goal(ogb):
    """OGBench >= 1.2 computes r(s) before the action; success terminates at the next step."""
    import mujoco

    env = ogb.OGBenchSingleTask(TASK)
    try:
        obs, _ = env.reset(seed=1)
        _, reward, terminated, _, info = env.step(np.zeros(5, np.float32))
        assert (reward, terminated, info["success"]) == (-1.0, False, False)
        inner = env._env.unwrapped
        inner._data.joint("object_joint_0").qpos[:3] = GOAL
        inner._data.joint("object_joint_0").qvel[:] = 0.0
        mujoco.mj_forward(inner._model, inner._data)
        _, reward, terminated, _, info = env.step(np.zeros(5, np.float32))
        assert reward == 0.0  # r(s): the cube is at the goal in s
        _, reward, terminated, _, info = env.step(np.zeros(5, np.float32))
        assert (reward, terminated, info["success"]) == (0.0, True, True)
    finally:
        env.close()


# ------------------------------------------------------------------------------------ unit
def test_unit_runs_end_to_end(ogb, tmp_path):
    from experiments.ogbench.unit import OGBenchBudget, run_ogbench_unit

    budget = OGBenchBudget(dataset_episodes=2, episode_steps=30, pretrain_steps=4, finetune_steps=25,
                           eval_episodes=2, curve_points=1, curve_episodes=1, max_episode_steps=20)
    record = run_ogbench_unit("fixed", TASK, 0, budget, tmp_path / "unit", data_dir=tmp_path / "data")
    assert record["dataset"]["transitions"] == 58
    assert record["algo_kwargs"]["entropy_threshold"] == "inf" and "chunk_size" not in record["algo_kwargs"]  # the default k
    assert [p["step"] for p in record["curve"]] == [0, 12, 25]
    assert record["curve"][0]["success"] == record["success_offline"] in (0.0, 0.5, 1.0)
    assert len(record["eval_online"]["successes"]) == 2
    # fixed chunks (δ = inf): every evaluation plan executes all k = 5 actions
    assert record["eval_offline"]["length_shares"] == record["eval_online"]["length_shares"] == [0, 0, 0, 0, 1.0]
    assert all(n <= 20 for n in record["eval_offline"]["lengths"] + record["eval_online"]["lengths"])
    assert len(record["training_episodes"]) >= 1  # 25 steps > one 20-step episode
    assert all(record["seconds"][f"{p}_cpu"] > 0 for p in ("pretrain", "finetune", "eval_offline", "eval_online"))
    on_disk = json.loads((tmp_path / "unit" / "record.json").read_text(), parse_constant=pytest.fail)
    assert on_disk["success_online"] == record["success_online"]
    assert (tmp_path / "unit" / "pretrained.zip").is_file() and (tmp_path / "unit" / "finetuned.zip").is_file()


def test_unit_rejects_bad_input(ogb, tmp_path):
    from experiments.ogbench.unit import OGBenchBudget, run_ogbench_unit

    with pytest.raises(ValueError, match="arm must be one of"):
        run_ogbench_unit("qc", TASK, 0, OGBenchBudget(), tmp_path)
    with pytest.raises(TypeError, match="budget must be an OGBenchBudget"):
        run_ogbench_unit("fixed", TASK, 0, {"pretrain_steps": 1}, tmp_path)
    with pytest.raises(ValueError, match="OGBenchBudget.pretrain_steps"):
        OGBenchBudget(pretrain_steps=0)
    with pytest.raises(ValueError, match="must not set"):
        OGBenchBudget(algo_kwargs={"entropy_threshold": math.inf})
    with pytest.raises(ValueError, match="unknown OGBenchBudget"):
        OGBenchBudget.from_dict({"steps": 1})
