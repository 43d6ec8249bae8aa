"""DrivingStyleContext (Eq. 6): observation space, contents, refresh rule, zoo and SubprocVecEnv use."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from style_helpers import FakeSlotEnv

from envs.style import DrivingStyleClassifier, StyleClassifierConfig
from envs.wrappers import DrivingStyleContext


@pytest.fixture(scope="module")
def classifier():
    return DrivingStyleClassifier(
        StyleClassifierConfig(seq_len=6, d_model=16, n_heads=2, dim_feedforward=16)
    ).eval()


def _expected_context(wrapper: DrivingStyleContext) -> np.ndarray:
    seqs = wrapper._sequences
    return wrapper.classifier.predict_proba(seqs.tokens, seqs.valid, empty=wrapper.empty)


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")
def test_observation_space_and_check_env(classifier):
    from stable_baselines3.common.env_checker import check_env

    env = DrivingStyleContext(FakeSlotEnv(), classifier=classifier)
    assert env.observation_space.shape == (20 + 18,)
    np.testing.assert_array_equal(env.observation_space.low[20:], 0.0)
    np.testing.assert_array_equal(env.observation_space.high[20:], 1.0)
    check_env(env, warn=True)
    from gymnasium.utils.env_checker import check_env as gym_check_env

    gym_check_env(env, skip_render_check=True)


def test_context_content_every_step(classifier):
    env = DrivingStyleContext(FakeSlotEnv(), classifier=classifier, update_every=1)
    obs, _ = env.reset(seed=0)
    for _ in range(8):
        ctx = obs[20:].reshape(6, 3)  # rows l_1, l_2, l_3, f_1, f_2, f_3
        np.testing.assert_allclose(ctx, _expected_context(env), atol=1e-6)
        np.testing.assert_array_equal(ctx[2], 0.0)  # l_3 is empty in FakeSlotEnv
        np.testing.assert_allclose(ctx[[0, 1, 3, 4, 5]].sum(1), 1.0, rtol=1e-5)
        assert env.observation_space.contains(obs)
        obs, *_ = env.step(env.action_space.sample())


def test_uniform_empty_output(classifier):
    env = DrivingStyleContext(FakeSlotEnv(), classifier=classifier, empty="uniform")
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs[20:].reshape(6, 3)[2], 1 / 3)


def test_refresh_period_and_occupant_change(classifier):
    env = DrivingStyleContext(FakeSlotEnv(), classifier=classifier, update_every=3)
    obs, _ = env.reset(seed=1)  # t=0: full refresh
    contexts = [obs[20:].reshape(6, 3)]
    np.testing.assert_allclose(contexts[0], _expected_context(env), atol=1e-6)
    assert env.n_forwards == 1
    for t in range(1, 7):
        obs, *_ = env.step(env.action_space.sample())
        ctx = obs[20:].reshape(6, 3)
        expected = _expected_context(env)
        if t % 3 == 0:
            np.testing.assert_allclose(ctx, expected, atol=1e-6)
        else:
            # unchanged occupants keep their previous distribution
            np.testing.assert_array_equal(ctx[[1, 3, 4, 5]], contexts[-1][[1, 3, 4, 5]])
            assert not np.allclose(ctx[1], expected[1])  # (so the check above is not vacuous)
        if t == 4:  # slot l_1 gets a new occupant at t=4 (FakeSlotEnv): unknown style until t=6
            assert env._sequences.changed[0] and env._sequences.lengths[0] == 1
            np.testing.assert_allclose(ctx[0], 1 / 3, rtol=1e-6)
        if t == 5:
            np.testing.assert_allclose(ctx[0], 1 / 3, rtol=1e-6)
        np.testing.assert_array_equal(ctx[2], 0.0)  # empty slot
        contexts.append(ctx)
    assert env.n_forwards == 3  # t = 0, 3, 6


def test_accepts_a_path_and_rl_zoo_wrapper_entry(classifier, tmp_path):
    path = tmp_path / "clf.pt"
    classifier.save(path)
    env = DrivingStyleContext(FakeSlotEnv(), classifier=str(path))
    obs, _ = env.reset(seed=0)
    ref = DrivingStyleContext(FakeSlotEnv(), classifier=classifier)
    np.testing.assert_allclose(obs, ref.reset(seed=0)[0], atol=1e-6)

    import rl_zoo3.utils as rl_zoo3_utils
    wrapper_cls = rl_zoo3_utils.get_wrapper_class(
        {
            "env_wrapper": [
                {"envs.wrappers.DrivingStyleContext": {"classifier": str(path), "update_every": 2}}
            ]
        }
    )
    wrapped = wrapper_cls(FakeSlotEnv())
    assert isinstance(wrapped, DrivingStyleContext) and wrapped.update_every == 2
    assert wrapped.reset(seed=0)[0].shape == (38,)


def test_bad_arguments(classifier):
    with pytest.raises(ValueError, match="update_every"):
        DrivingStyleContext(FakeSlotEnv(), classifier=classifier, update_every=0)
    with pytest.raises(ValueError, match="empty"):
        DrivingStyleContext(FakeSlotEnv(), classifier=classifier, empty="nan")
    with pytest.raises(ValueError, match="classifier"):
        DrivingStyleContext(FakeSlotEnv(), classifier=3.5)
    with pytest.raises(ValueError, match="Box"):
        DrivingStyleContext(_DiscreteObsEnv(), classifier=classifier)
    env = DrivingStyleContext(_NoSlotsEnv(), classifier=classifier)
    with pytest.raises(ValueError, match="slots"):
        env.reset(seed=0)


class _NoSlotsEnv(FakeSlotEnv):
    def _info(self):
        return {}


class _DiscreteObsEnv(FakeSlotEnv):
    def __init__(self):
        super().__init__()
        self.observation_space = gym.spaces.Discrete(3)


def test_pickle_and_subproc_vec_env(classifier):
    env = DrivingStyleContext(FakeSlotEnv(), classifier=classifier)
    env.reset(seed=0)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.observation_space == env.observation_space

    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = SubprocVecEnv([lambda: DrivingStyleContext(FakeSlotEnv(), classifier=classifier)] * 2)
    try:
        obs = vec.reset()
        assert obs.shape == (2, 38)
        obs, *_ = vec.step(np.zeros((2, 2), dtype=np.float32))
        np.testing.assert_allclose(obs[:, 20:].reshape(2, 6, 3)[:, [0, 1, 3, 4, 5]].sum(-1), 1.0, rtol=1e-5)
    finally:
        vec.close()


def test_mixed_traffic_observation_grows_from_20_to_38(classifier):
    from stable_baselines3.common.env_checker import check_env

    import envs  # noqa: F401  (registers MixedTraffic-v0)

    clf = DrivingStyleClassifier(StyleClassifierConfig(d_model=16, n_heads=2, dim_feedforward=16)).eval()
    env = DrivingStyleContext(gym.make("MixedTraffic-v0"), classifier=clf, update_every=1)
    try:
        assert env.unwrapped.observation_space.shape == (20,)
        assert env.observation_space.shape == (38,)
        check_env(env, warn=True)
        obs, info = env.reset(seed=0)
        for _ in range(20):
            ctx = obs[20:].reshape(6, 3)
            present = info["slots"]["present"]
            np.testing.assert_allclose(ctx[present].sum(1), 1.0, rtol=1e-5)
            np.testing.assert_array_equal(ctx[~present], 0.0)
            obs, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
            if terminated or truncated:
                break
    finally:
        env.close()


def test_packaged_classifier_is_the_default():
    from envs.style import DEFAULT_CLASSIFIER_PATH

    assert DEFAULT_CLASSIFIER_PATH.is_file(), "the package ships its default classifier (setup.cfg package_data)"
    env = DrivingStyleContext(FakeSlotEnv())
    assert env.classifier.config.seq_len == 20
    assert env.reset(seed=0)[0].shape == (38,)
