"""Save/load round trips, set_parameters, resuming from loaded weights, determinism, bad arguments."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.evaluation import evaluate_policy
from ua2c_helpers import FAST, rollout_actions

from sb3_ua2c import UA2C
from sb3_ua2c.buffers import ChunkReplayBuffer


def params(model: UA2C) -> dict[str, th.Tensor]:
    return {k: v.clone() for k, v in model.policy.state_dict().items()}



def test_save_load_same_actions_and_hyperparameters(tmp_path):
    model = UA2C(
        "MlpPolicy", "Pendulum-v1", seed=0, chunk_size=4, history_len=3, entropy_threshold=-0.5,
        smooth_weight=2.5, **FAST
    )
    model.learn(120)
    before = rollout_actions(model)
    model.save(tmp_path / "ua2c.zip")
    loaded = UA2C.load(tmp_path / "ua2c.zip")
    assert (loaded.chunk_size, loaded.history_len, loaded.execution.entropy_threshold) == (4, 3, -0.5)
    assert loaded.smooth_weight == 2.5
    assert loaded.policy.critic_kwargs == {"embed_dim": 16, "n_layers": 1, "n_heads": 1, "ff_dim": 32}
    for k, v in params(model).items():
        assert th.equal(v, loaded.policy.state_dict()[k]), k
    np.testing.assert_array_equal(rollout_actions(loaded), before)
    # optimizer states are restored as well
    assert (
        loaded.actor.optimizer.state_dict()["state"].keys()
        == model.actor.optimizer.state_dict()["state"].keys()
    )


def test_deterministic_predict_is_a_function_of_the_history():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    obs = np.array([1.0, 0.0, 0.5], np.float32)
    a1, _ = model.predict(obs, deterministic=True)
    a2, _ = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(a1, a2)


def test_predict_leaves_the_networks_in_eval_mode():
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    obs = np.array([1.0, 0.0, 0.5], np.float32)
    model.policy.set_training_mode(False)
    a_eval, _ = model.predict(obs, deterministic=True)
    switches = [model.actor.train, model.critic.train, model.policy.set_training_mode]
    for switch in switches:  # predict after a train() of the actor, the critics or the whole policy
        switch(True)
        a, _ = model.predict(obs, deterministic=True)
        assert not model.actor.training and not model.critic.training
        assert not any(m.training for m in model.critic.modules())
        np.testing.assert_array_equal(a, a_eval)


def test_set_parameters_and_resume_from_loaded_weights(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST).learn(100)
    model.save(tmp_path / "m.zip")
    saved = params(model)
    other = UA2C("MlpPolicy", "Pendulum-v1", seed=1, **FAST)
    other.set_parameters(str(tmp_path / "m.zip"))
    for k, v in saved.items():
        assert th.equal(v, other.policy.state_dict()[k]), k
    # load with an env and keep learning: the first update starts from the loaded weights
    resumed = UA2C.load(tmp_path / "m.zip", env=gym.make("Pendulum-v1"), learning_starts=1000)
    resumed.learn(30, reset_num_timesteps=False)  # still warm-up for the fresh buffer: no update
    for k, v in saved.items():
        assert th.equal(v, resumed.policy.state_dict()[k]), k
    n_updates = resumed._n_updates
    resumed.learning_starts = 0
    resumed.learn(60, reset_num_timesteps=False)
    assert resumed._n_updates > n_updates
    assert any(not th.equal(v, resumed.policy.state_dict()[k]) for k, v in saved.items())


def test_loading_mismatched_networks_raises_a_clear_error(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    state = model.policy.state_dict()
    # a critic of an early development version: layer norms with a bias
    old = {**state, "critic.blocks.0.norm1.bias": th.zeros_like(state["critic.blocks.0.norm1.weight"])}
    with pytest.raises(ValueError, match="layer-norm biases"):
        model.set_parameters({"policy": old})
    model.save(tmp_path / "m.zip")
    other = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **{**FAST, "chunk_size": 3})
    with pytest.raises(ValueError, match="do not match this UA2C model") as info:
        other.set_parameters(str(tmp_path / "m.zip"))
    assert "layer-norm" not in str(info.value) and "size mismatch" in str(info.value)


def test_replay_buffer_save_load(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST).learn(80)
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    fresh = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    fresh.load_replay_buffer(tmp_path / "buffer.pkl")
    assert isinstance(fresh.replay_buffer, ChunkReplayBuffer)
    assert fresh.replay_buffer.n_samples() == model.replay_buffer.n_samples()


def test_same_seed_gives_bit_identical_weights():
    a = UA2C("MlpPolicy", "Pendulum-v1", seed=7, **FAST).learn(120)
    b = UA2C("MlpPolicy", "Pendulum-v1", seed=7, **FAST).learn(120)
    c = UA2C("MlpPolicy", "Pendulum-v1", seed=8, **FAST).learn(120)
    pa, pb, pc = params(a), params(b), params(c)
    assert all(th.equal(pa[k], pb[k]) for k in pa)
    assert not all(th.equal(pa[k], pc[k]) for k in pa)


def pendulum_episode(seed: int, steps: int | None = None) -> dict[str, np.ndarray]:
    """A logged Pendulum-v1 episode of seeded uniform random torques in env units ([-2, 2]), to its
    time limit or truncated after ``steps`` steps."""
    env = gym.make("Pendulum-v1")
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rows: dict[str, list] = dict(observations=[obs], actions=[], rewards=[], terminations=[], truncations=[])
    term = trunc = False
    while not (term or trunc):
        action = rng.uniform(-2.0, 2.0, size=1).astype(np.float32)
        obs, reward, term, trunc, _ = env.step(action)
        trunc = trunc or len(rows["actions"]) + 1 == steps
        for key, value in zip(
            ("actions", "rewards", "terminations", "truncations"), (action, reward, term, trunc), strict=True
        ):
            rows[key].append(value)
        rows["observations"].append(obs)
    env.close()
    return {k: np.array(v) for k, v in rows.items()}


def test_offline_episodes_and_pretrain_without_env_interaction():
    episodes = [pendulum_episode(seed) for seed in range(2)]
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, offline_ratio=0.5, **FAST)
    assert model.add_offline_episodes(episodes) == 400
    stored = model.replay_buffer.offline.actions[:200, 0, 0]
    np.testing.assert_allclose(
        stored, episodes[0]["actions"][:, 0] / 2.0, atol=1e-6
    )  # Pendulum torque in [-2, 2]
    before = params(model)
    model.pretrain(5, log_interval=2)
    assert model._n_updates == 5 and model.num_timesteps == 0
    assert any(not th.equal(v, model.policy.state_dict()[k]) for k, v in before.items())
    with pytest.raises(ValueError, match="n_gradient_steps"):
        model.pretrain(-1)
    with pytest.raises(ValueError, match="needs data"):
        UA2C("MlpPolicy", "Pendulum-v1", **FAST).pretrain(1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(chunk_size=0), "chunk_size"),
        (dict(history_len=1.5), "history_len"),
        (dict(flow_steps=-1), "flow_steps"),
        (dict(n_candidates=0), "n_candidates"),
        (dict(n_target_candidates=0), "n_target_candidates"),
        (dict(target_flow_steps=0), "target_flow_steps"),
        (dict(entropy_threshold=math.nan), "entropy_threshold"),
        (dict(entropy_threshold=-math.inf), "entropy_threshold"),
        (dict(entropy_threshold="high"), "entropy_threshold"),
        (dict(q_weight=-1.0), "q_weight"),
        (dict(smooth_weight=-1.0), "smooth_weight"),
        (dict(smooth_weight=math.inf), "smooth_weight"),
        (dict(smooth_weight="1"), "smooth_weight"),
        (dict(offline_ratio=2.0), "offline_ratio"),
        (dict(discrete_action_dims={3: [-1, 0, 1]}), "discrete_action_dims"),
        (dict(batch_size=0), "batch_size"),
        (dict(gamma=1.5), "gamma"),
        (dict(policy_kwargs=dict(critic_kwargs=dict(embed_dim=0))), r"critic_kwargs\['embed_dim'\]"),
        (dict(policy_kwargs=dict(critic_kwargs=dict(embed_dim=30, n_heads=4))), r"critic_kwargs\['n_heads'\]"),
        (dict(policy_kwargs=dict(critic_embed_dim=32)), "use critic_kwargs="),
        (dict(policy_kwargs=dict(n_layers=2)), "n_layers"),
        (dict(policy_kwargs=dict(chunk_size=2)), "chunk_size"),
        (dict(replay_buffer_class=dict), "replay_buffer_class"),
    ],
)
def test_bad_hyperparameters_raise_value_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", "Pendulum-v1", **kwargs)


class DictObsEnv(gym.Env):
    observation_space = spaces.Dict({"x": spaces.Box(-1, 1, (2,))})
    action_space = spaces.Box(-1, 1, (1,))

    def reset(self, *, seed=None, options=None):
        return {"x": np.zeros(2, np.float32)}, {}

    def step(self, action):
        return {"x": np.zeros(2, np.float32)}, 0.0, False, False, {}


@pytest.mark.parametrize(
    ("env", "match"),
    [
        ("CartPole-v1", "Box action spaces only, got Discrete"),
        (DictObsEnv(), "Box observation spaces only, got Dict"),
    ],
)
def test_unsupported_spaces_raise(env, match):
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", env)


def test_evaluate_policy_after_load(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    model.save(tmp_path / "m")
    loaded = UA2C.load(tmp_path / "m")
    mean, _ = evaluate_policy(loaded, gym.make("Pendulum-v1"), n_eval_episodes=1, warn=False)
    assert -2000.0 < mean < 0.0


#: the tiny settings, acting by the best of 4 candidates
BEST_OF_4 = {**FAST, "n_candidates": 4, "policy_kwargs": {**FAST["policy_kwargs"], "n_elite": 1}}


def test_set_n_elite_changes_execution_and_is_saved(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **BEST_OF_4)
    obs = np.zeros(3, dtype=np.float32)
    best, _ = model.predict(obs, deterministic=True)
    model.set_n_elite(4)  # the mean of all 4 candidates
    mean, _ = model.predict(obs, deterministic=True)
    assert model.policy.n_elite == 4 and not np.allclose(best, mean)
    assert BEST_OF_4["policy_kwargs"]["n_elite"] == 1  # the caller's policy_kwargs are not changed
    model.save(tmp_path / "m.zip")
    loaded = UA2C.load(tmp_path / "m.zip")
    assert loaded.policy.n_elite == 4
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], mean)
    for bad in (0, 5, 1.5):
        with pytest.raises(ValueError, match="n_elite"):
            model.set_n_elite(bad)


def test_load_n_elite_override_sets_the_policy(tmp_path):
    """``UA2C.load(path, n_elite=m)`` acts by the elite mean of m, as ``set_n_elite`` does."""
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **BEST_OF_4)
    model.save(tmp_path / "m.zip")
    obs = np.zeros(3, dtype=np.float32)
    model.set_n_elite(4)
    mean, _ = model.predict(obs, deterministic=True)
    loaded = UA2C.load(tmp_path / "m.zip", n_elite=4)
    assert loaded.policy.n_elite == 4 and loaded.policy_kwargs["n_elite"] == 4
    assert "n_elite" not in loaded.__dict__  # not left behind as an unused attribute
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], mean)
    loaded.save(tmp_path / "m4.zip")  # and kept by save
    assert UA2C.load(tmp_path / "m4.zip").policy.n_elite == 4
    assert UA2C.load(tmp_path / "m.zip").policy.n_elite == 1  # the file itself is unchanged
    with pytest.raises(ValueError, match="n_elite=5 must not exceed n_candidates=4"):
        UA2C.load(tmp_path / "m.zip", n_elite=5)
    with pytest.raises(ValueError, match="n_elite"):
        UA2C.load(tmp_path / "m.zip", n_elite=0)


def test_set_flow_steps_changes_the_sampler_and_is_saved(tmp_path):
    from sb3_ua2c.policies import history_noise

    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **BEST_OF_4)
    policy = model.policy
    obs = th.tensor([[0.3, -0.2, 0.5]])
    model.set_flow_steps(1)
    assert model.flow_steps == policy.flow_steps == 1
    with th.no_grad():
        got = policy._predict(obs, deterministic=True)  # (1, action_dim), first action of the plan
        # by hand: one Euler step x1 = x0 + v(x0, 0 | h), then best-of-S by min_j Q_j
        history = obs.reshape(1, 1, -1).expand(-1, policy.history_len, -1)
        cond = policy.actor.condition(policy.flatten_history(history, th.zeros(1, policy.history_len, 1)))
        x0 = history_noise(history, th.zeros(1, policy.history_len, 1), 4, policy.chunk_size)  # (1, S, k, 1)
        x1 = (x0 + policy.actor(x0, th.zeros(()), cond)).clamp(-1.0, 1.0)
        q = policy.critic(history.reshape(1, -1), x1).min(dim=0).values  # (1, S)
        expected = x1[0, q[0].argmax(), 0]
    assert th.allclose(got[0], expected, atol=1e-6)
    model.save(tmp_path / "m.zip")
    loaded = UA2C.load(tmp_path / "m.zip")
    assert loaded.policy.flow_steps == loaded.flow_steps == 1
    # a load override reaches the policy and the config, and is validated like the constructor argument
    assert UA2C.load(tmp_path / "m.zip", flow_steps=3).policy.flow_steps == 3
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="flow_steps"):
            model.set_flow_steps(bad)
        with pytest.raises(ValueError, match="flow_steps"):
            UA2C.load(tmp_path / "m.zip", flow_steps=bad)


def test_discrete_entropy_is_validated_saved_and_overridable(tmp_path):
    env = gym.make("Pendulum-v1")
    with pytest.raises(ValueError, match="discrete_entropy"):
        UA2C("MlpPolicy", env, discrete_entropy="no", **FAST)
    model = UA2C("MlpPolicy", env, seed=0, discrete_entropy=False, **FAST)
    assert model.policy.discrete_entropy is False and model.discrete_entropy is False
    model.save(tmp_path / "m.zip")
    assert UA2C.load(tmp_path / "m.zip").policy.discrete_entropy is False
    loaded = UA2C.load(tmp_path / "m.zip", discrete_entropy=True)  # a Phase-2 override reaches the policy
    assert loaded.policy.discrete_entropy is True and loaded.discrete_entropy is True


def test_online_targets_is_validated_saved_and_overridable(tmp_path):
    env = gym.make("Pendulum-v1")
    with pytest.raises(ValueError, match="online_targets"):
        UA2C("MlpPolicy", env, online_targets="windows", **FAST)
    model = UA2C("MlpPolicy", env, seed=0, online_targets="window", **FAST)
    assert model.replay_buffer.online_targets == model.online_targets == "window"
    model.learn(80)
    # every executed step of the 80 starts a sample once its k = 5 next steps are stored
    assert model.replay_buffer.n_samples() == (80 - 4, 0)
    model.save(tmp_path / "m.zip")
    assert UA2C.load(tmp_path / "m.zip").replay_buffer.online_targets == "window"
    loaded = UA2C.load(tmp_path / "m.zip", online_targets="prefix")  # e.g. a Phase-2 override
    assert loaded.replay_buffer.online_targets == loaded.online_targets == "prefix"
    with pytest.raises(ValueError, match="online_targets"):
        UA2C.load(tmp_path / "m.zip", online_targets="eq4")


@pytest.mark.parametrize(("offline", "chosen"), [(False, "window"), (True, "prefix")])
def test_default_online_targets_train_as_the_measured_best_choice(tmp_path, offline, chosen):
    """
    The default "auto" is Eq. 8 offline-to-online and windows online only: the same parameters,
    bit for bit, as the explicit choice; the setting is saved, the choice is made again online.
    """
    trained = {}
    for targets in ("auto", chosen):
        model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, online_targets=targets, **FAST)
        if offline:
            model.add_offline_episodes([pendulum_episode(1, steps=30), pendulum_episode(2, steps=30)])
        model.learn(150)
        assert model.replay_buffer.active_online_targets == chosen
        trained[targets] = params(model)
    assert UA2C("MlpPolicy", "Pendulum-v1", **FAST).online_targets == "auto"
    for k, v in trained["auto"].items():
        assert th.equal(v, trained[chosen][k]), k
    model.save(tmp_path / "m.zip")
    assert UA2C.load(tmp_path / "m.zip").replay_buffer.active_online_targets == chosen  # explicit setting
    auto = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **FAST)
    auto.save(tmp_path / "auto.zip")
    loaded = UA2C.load(tmp_path / "auto.zip")
    assert loaded.online_targets == "auto" and loaded.replay_buffer.active_online_targets is None


def test_commit_discrete_is_validated_saved_and_overridable(tmp_path):
    env = gym.make("Pendulum-v1")
    with pytest.raises(ValueError, match="commit_discrete"):
        UA2C("MlpPolicy", env, commit_discrete="yes", **FAST)
    model = UA2C("MlpPolicy", env, seed=0, commit_discrete=True, discrete_action_dims={0: [-1, 1]}, **FAST)
    assert model.policy.commit_discrete is True and model.commit_discrete is True
    model.save(tmp_path / "m.zip")
    assert UA2C.load(tmp_path / "m.zip").policy.commit_discrete is True
    loaded = UA2C.load(tmp_path / "m.zip", commit_discrete=False)  # e.g. a Phase-2 override
    assert loaded.policy.commit_discrete is False and loaded.commit_discrete is False
    with pytest.raises(ValueError, match="commit_discrete"):
        UA2C.load(tmp_path / "m.zip", commit_discrete=0)
