"""The pretrained Phase-1 checkpoint shipped in ``rl-trained-agents/`` (rl-zoo's trained-agents layout).

Made by ``python -m experiments make-checkpoint --out rl-trained-agents``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from sb3_ua2c import UA2C

REPO = Path(__file__).resolve().parents[2]
FOLDER = REPO / "rl-trained-agents"
ENV_ID = "MixedTraffic-v0"
EXPERIMENT = FOLDER / "ua2c" / f"{ENV_ID}_1"
CHECKPOINT = EXPERIMENT / f"{ENV_ID}.zip"
PARAMS = EXPERIMENT / ENV_ID

#: Constructor arguments and zoo keys the checkpoint shares with ``zoo_configs/ua2c.yml``: what
#: decides the networks' shapes and the observation (``train -i`` and ``enjoy`` need them equal).
SHARED_KEYS = ("chunk_size", "history_len", "policy_kwargs", "discrete_action_dims", "env_wrapper", "policy")


def _saved_hyperparams() -> dict:
    from rl_zoo3 import get_saved_hyperparams

    hyperparams, stats_path = get_saved_hyperparams(str(PARAMS), test_mode=True)
    assert stats_path == str(PARAMS)
    return hyperparams


@pytest.fixture(scope="module")
def model() -> UA2C:
    return UA2C.load(CHECKPOINT, device="cpu")


@pytest.fixture
def zoo_env():
    """The env as rl-zoo's ``enjoy`` builds it from the folder's ``config.yml`` (with its ``env_wrapper``)."""
    from rl_zoo3 import create_test_env

    import envs  # noqa: F401  (registers MixedTraffic-v0)

    env = create_test_env(
        ENV_ID, n_envs=1, stats_path=None, seed=0, log_dir=None, should_render=False,
        hyperparams=_saved_hyperparams(), env_kwargs={},
    )
    yield env
    env.close()


def test_folder_has_the_rl_zoo_files():
    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_model_path

    for path in (CHECKPOINT, PARAMS / "config.yml", PARAMS / "args.yml", EXPERIMENT / "README.md"):
        assert path.is_file(), path
    # what `enjoy -f rl-trained-agents` (latest experiment) and `--exp-id 1` load
    for exp_id in (0, 1):
        _, model_path, log_path = get_model_path(exp_id, str(FOLDER), "ua2c", EnvironmentName(ENV_ID))
        assert Path(model_path) == CHECKPOINT and Path(log_path) == EXPERIMENT
    with open(PARAMS / "args.yml") as f:
        args = yaml.load(f, Loader=yaml.UnsafeLoader)
    assert (args["algo"], args["env"], args["env_kwargs"]) == ("ua2c", ENV_ID, None)
    for path in PARAMS.iterdir():  # no path of the machine that made it
        assert str(REPO) not in path.read_text() and "/tmp/" not in path.read_text(), path


def test_size_is_about_one_megabyte():
    assert CHECKPOINT.stat().st_size <= 1_500_000


def test_config_matches_the_zoo_config():
    """What ``train -i`` and ``enjoy`` need equal: the keys the zoo entry states, and the shapes it leaves
    to the library's defaults (rl-zoo3 drops ``policy_kwargs`` when it continues a checkpoint)."""
    from sb3_ua2c.defaults import defaults

    with open(REPO / "zoo_configs" / "ua2c.yml") as f:
        entry = yaml.safe_load(f)[ENV_ID]
    saved = _saved_hyperparams()
    stated = [k for k in SHARED_KEYS if k in entry]
    assert {k: saved.get(k) for k in stated} == {k: entry[k] for k in stated}
    assert {"discrete_action_dims", "env_wrapper", "policy"} <= set(stated)
    for key in ("chunk_size", "history_len"):
        assert saved.get(key, defaults()[key]) == entry.get(key, defaults()[key]), key


def test_loads_and_has_the_zoo_env_spaces(model, zoo_env):
    assert model.observation_space == zoo_env.observation_space
    assert model.action_space == zoo_env.action_space
    assert model.observation_space.shape == (38,)  # 20 numbers + the driving-style context c_t (Eq. 6)
    assert (model.chunk_size, model.history_len) == (5, 4)


def test_predict_on_a_reset_observation(model, zoo_env):
    obs = zoo_env.reset()
    action, state = model.predict(obs, state=None, episode_start=np.ones(1, dtype=bool), deterministic=True)
    assert action.shape == (1, *zoo_env.action_space.shape)
    assert zoo_env.action_space.contains(action[0].astype(zoo_env.action_space.dtype))
    obs, reward, done, infos = zoo_env.step(action)
    assert np.isfinite(reward).all()


def test_the_script_uses_the_main_budget():
    from envs.cli import MAIN_BUDGET
    from experiments.pretrained import make_checkpoint

    full = MAIN_BUDGET["full"]
    assert (make_checkpoint.EPISODES, make_checkpoint.PRETRAIN_STEPS, make_checkpoint.EVAL_EPISODES) == (
        full["episodes"], full["pretrain_steps"], full["eval_episodes"]
    )
    assert make_checkpoint.checkpoint_path(FOLDER) == CHECKPOINT


def test_is_the_phase_1_checkpoint(model):
    # 3,000 offline gradient steps (MAIN_BUDGET), no online step yet
    assert (model._n_updates, model.num_timesteps) == (3000, 0)


def _zoo(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sb3_ua2c.zoo", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_zoo_enjoy_runs_it():
    result = _zoo("enjoy", "--algo", "ua2c", "--env", ENV_ID, "--gym-packages", "envs", "-f", "rl-trained-agents",
                  "-n", "30", "--no-render", "--num-threads", "1")  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"Loading rl-trained-agents/ua2c/{ENV_ID}_1/{ENV_ID}.zip" in result.stdout


@pytest.mark.slow  # 7-10 s on 2 cores: rl-zoo3 trains in SubprocVecEnv workers
def test_zoo_train_continues_from_it(tmp_path):
    result = _zoo("train", "--algo", "ua2c", "--env", ENV_ID, "--gym-packages", "envs",
                  "--conf-file", str(REPO / "zoo_configs" / "ua2c.yml"), "-i", str(CHECKPOINT), "-n", "20",
                  "-f", str(tmp_path), "--eval-freq", "-1", "--num-threads", "1", "--verbose", "0",
                  "-params", "learning_starts:0")  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    tuned = UA2C.load(tmp_path / "ua2c" / f"{ENV_ID}_1" / f"{ENV_ID}.zip", device="cpu")
    assert tuned.num_timesteps == 20 and tuned._n_updates > 3000  # online steps on top of Phase 1
