"""sb3-contrib-style smoke tests: UA2C trains and predicts on Pendulum and generic Box envs (tiny nets)."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize
from ua2c_helpers import FAST

from sb3_ua2c import UA2C, UA2CPolicy


class TwoDimEnv(gym.Env):
    """Box(3) observations, Box(2) actions: dim 0 continuous, dim 1 a 3-way choice (like a lane change)."""

    observation_space = spaces.Box(-10.0, 10.0, (3,), np.float32)
    action_space = spaces.Box(np.array([-3.0, -1.0], np.float32), np.array([2.0, 1.0], np.float32))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.normal(size=3).astype(np.float32), {}

    def step(self, action):
        assert self.action_space.contains(np.asarray(action, np.float32))
        self.t += 1
        obs = self.np_random.normal(size=3).astype(np.float32)
        lane = int(np.digitize(action[1], [-1 / 3, 1 / 3])) - 1
        reward = -float(action[0] ** 2) - abs(lane)
        return obs, reward, self.t >= 30 and self.np_random.random() < 0.5, self.t >= 40, {}


def test_pendulum_learn_predict_and_logger_keys():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    model.set_logger(configure(None, ["csv"]))
    model.learn(150, log_interval=1)
    values = model.logger.name_to_value
    assert model.num_timesteps == 150
    assert {"train/actor_loss", "train/critic_loss", "train/flow_loss"} <= set(values)
    assert model._n_updates > 0
    assert 1.0 <= model.last_executed_length <= model.chunk_size
    action, state = model.predict(np.zeros(3, np.float32))
    assert action.shape == (1,) and -2.0 <= action[0] <= 2.0
    assert state is not None and state.plan.shape == (1, 5, 1)


def _trained_actor(chunk_size: int, smooth_weight: float) -> tuple[UA2C, list[np.ndarray]]:
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=chunk_size, smooth_weight=smooth_weight, **FAST)
    model.set_logger(configure(None, ["csv"]))
    model.learn(120, log_interval=1)
    return model, [p.detach().numpy().copy() for p in model.actor.parameters()]


def test_smooth_weight_acts_on_chunks_only():
    # k = 1: a one-step chunk has no step inside it, so mu changes nothing, bit for bit
    _, plain = _trained_actor(1, 0.0)
    _, smooth = _trained_actor(1, 50.0)
    assert all(np.array_equal(a, b) for a, b in zip(plain, smooth, strict=True))
    # k = 5: the term trains the actor and is logged
    model, smooth = _trained_actor(5, 50.0)
    _, plain = _trained_actor(5, 0.0)
    assert not all(np.array_equal(a, b) for a, b in zip(plain, smooth, strict=True))
    assert model.logger.name_to_value["train/roughness"] >= 0.0
    assert model.smooth_weight == 50.0


def test_rollout_logs_executed_length_and_entropy():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    model.set_logger(configure(None, []))
    dumped = []
    dump = model.logger.dump

    def capture(step: int = 0) -> None:
        dumped.append(dict(model.logger.name_to_value))
        dump(step)

    model.logger.dump = capture
    model.learn(200, log_interval=1)  # the first episode (200 steps) ends with a dump
    values = dumped[-1]
    assert 1.0 <= values["rollout/executed_length"] <= 5.0
    assert np.isfinite(values["rollout/entropy_mean"])
    assert {"rollout/entropy_first", "rollout/entropy_last"} <= set(values)


@pytest.mark.parametrize("chunk_size, entropy_threshold", [(1, 0.0), (4, math.inf), (3, -100.0)])
def test_one_step_fixed_and_adaptive_share_the_code_path(chunk_size, entropy_threshold):
    model = UA2C(
        "MlpPolicy", "Pendulum-v1", seed=0, chunk_size=chunk_size, entropy_threshold=entropy_threshold, **FAST
    )
    model.learn(120)
    lengths = set(model._plan_lengths)
    if chunk_size == 1 or entropy_threshold < 0:
        assert lengths == {1.0}  # one-step baseline / every position unreliable
    else:
        assert lengths == {float(chunk_size)}  # fixed chunk execution


def test_discrete_action_dims_vectorized_envs_and_action_noise():
    env = make_vec_env(TwoDimEnv, n_envs=2, seed=0)
    model = UA2C(
        "MlpPolicy",
        env,
        discrete_action_dims={1: [-1, 0, 1]},
        action_noise=NormalActionNoise(np.zeros(2), 0.1 * np.ones(2)),
        seed=0,
        **FAST,
    )
    model.learn(200)
    assert model.policy.discrete_dims == {1: 3}
    assert model.replay_buffer.n_samples()[0] > 0
    actions, _ = model.predict(env.reset())
    assert actions.shape == (2, 2)


def test_subproc_vec_env():
    env = make_vec_env(
        "Pendulum-v1", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv, vec_env_kwargs=dict(start_method="fork")
    )
    try:
        model = UA2C("MlpPolicy", env, seed=0, **FAST).learn(140)
        assert model.num_timesteps == 140
    finally:
        env.close()


def test_vec_normalize():
    env = VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]))
    model = UA2C("MlpPolicy", env, seed=0, **FAST).learn(120)
    assert model._n_updates > 0


def test_evaluate_policy_and_eval_callback_use_the_state():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    eval_env = make_vec_env("Pendulum-v1", n_envs=1, seed=1)
    callback = EvalCallback(eval_env, n_eval_episodes=1, eval_freq=100)
    model.learn(100, callback=callback)
    assert callback.n_calls == 100 and -2000.0 < callback.last_mean_reward < 0.0
    mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=1)
    assert -2000.0 < mean < 0.0


def test_progress_bar(capsys):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST).learn(60, progress_bar=True)
    assert model.num_timesteps == 60
    assert "60/60" in capsys.readouterr().out  # SB3's bar counted every environment step


def test_policy_aliases():
    assert UA2C.policy_aliases == {"MlpPolicy": UA2CPolicy}
    by_alias = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    by_class = UA2C(UA2CPolicy, "Pendulum-v1", seed=0, **FAST)
    assert type(by_alias.policy) is type(by_class.policy) is UA2CPolicy
    # the same policy, built from the same seed: the same initial weights
    pairs = zip(by_alias.policy.parameters(), by_class.policy.parameters(), strict=True)
    assert all(np.array_equal(a.detach().numpy(), b.detach().numpy()) for a, b in pairs)
    with pytest.raises(ValueError, match="Policy CnnPolicy unknown"):
        UA2C("CnnPolicy", "Pendulum-v1", **FAST)


@pytest.mark.parametrize(("chunk_size", "expected_updates"), [(4, 10), (1, 40)])
def test_paper_cadence_is_one_gradient_step_per_plan_and_the_default_one_per_env_step(chunk_size, expected_updates):
    kwargs = {**FAST, "learning_starts": 40}
    model = UA2C(
        "MlpPolicy", "Pendulum-v1", seed=0, chunk_size=chunk_size, entropy_threshold=math.inf, gradient_steps=-1,
        **kwargs,
    )
    model.learn(80)  # 40 policy steps after the warm-up: 10 plans of 4 actions, or 40 of 1
    assert model._n_updates == expected_updates
    sb3_cadence = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=4, **kwargs).learn(80)
    assert sb3_cadence._n_updates == 40  # the default, 1: SB3's meaning (per rollout step)
