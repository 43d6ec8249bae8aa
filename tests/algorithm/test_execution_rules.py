"""The execution rules (``execution_rule``): hand-computed lengths and thresholds, the invariance of the
scale-free rules to the units of the actions, the standardised deterministic noise, calibration, and what
a model saved under one rule does after a load."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from ua2c_helpers import FAST

from sb3_ua2c import UA2C
from sb3_ua2c.chunking import (
    chunk_entropy,
    entropy_growth_length,
    executable_prefix_length,
    quantile_entropy_thresholds,
)
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.policies import history_noise


def test_growth_length_by_hand():
    entropy = th.tensor([
        [1.0, 1.2, 1.6, 1.1],  # H - H_1 = [0, .2, .6, .1]: position 3 ends the prefix -> 2
        [3.0, 2.0, 3.4, 9.0],  # [0, -1, .4, 6]: a drop below H_1 is reliable -> 3
        [5.0, 9.0, 5.0, 5.0],  # [0, 4, 0, 0]: a prefix, not a count -> 1
        [-7.0, -7.0, -6.6, -6.5],  # [0, 0, .4, .5]: the bound is inclusive -> 4
    ])
    assert entropy_growth_length(entropy, 0.5).tolist() == [2, 3, 1, 4]
    assert entropy_growth_length(entropy, 0.0).tolist() == [1, 2, 1, 2]
    # H_1 gates nothing: a first position far above any absolute δ still executes its flat prefix
    assert entropy_growth_length(th.tensor([[50.0, 50.0, 50.1]]), 0.2).tolist() == [3]


def test_quantile_thresholds_by_hand():
    entropy = th.tensor([[1.0, 0.0], [2.0, 10.0], [3.0, 20.0], [4.0, 30.0], [math.nan, math.nan]])
    # torch.quantile's linear interpolation: position 1 at q = 0.5 -> 2.5; position 2 at q = 0.75 -> 22.5
    assert quantile_entropy_thresholds(entropy, 0.5).tolist() == [2.5, 15.0]
    assert quantile_entropy_thresholds(entropy, 0.75).tolist() == [3.25, 22.5]
    assert quantile_entropy_thresholds(entropy, 1.0).tolist() == [4.0, 30.0]  # the NaN row is ignored
    lengths = executable_prefix_length(th.tensor([[2.0, 16.0], [2.0, 14.0], [3.0, 0.0]]), th.tensor([2.5, 15.0]))
    assert lengths.tolist() == [1, 2, 1]


def known_spreads(rng: np.random.Generator, spreads: np.ndarray, s: int = 64) -> th.Tensor:
    """Candidates ``(B, S, k, 2)`` with standard deviation ``spreads[b, u]`` at row b, position u (both dims)."""
    b, k = spreads.shape
    noise = rng.standard_normal((b, s, k, 2))
    noise = (noise - noise.mean(axis=1, keepdims=True)) / noise.std(axis=1, ddof=1, keepdims=True)
    return th.as_tensor(0.05 * noise * spreads[:, None, :, None], dtype=th.float32)  # inside [-1, 1] even ×10


def lengths_under(samples: th.Tensor, calibration: th.Tensor) -> dict[str, list[int]]:
    """``L_t`` of every row under the three rules (quantile thresholds measured on ``calibration``)."""
    entropy = chunk_entropy(samples, discrete=True)
    thresholds = quantile_entropy_thresholds(chunk_entropy(calibration, discrete=True), 0.5)
    return {
        "growth": entropy_growth_length(entropy, 0.3).tolist(),
        "quantile": executable_prefix_length(entropy, thresholds).tolist(),
        "threshold": executable_prefix_length(entropy, -3.0).tolist(),
    }


def test_scale_free_rules_ignore_the_units_of_the_actions():
    """Rescaling every action ×10, or adding a constant action dimension, shifts every ``H_u`` by one
    constant: the growth and quantile rules keep every ``L_t``; an absolute δ does not."""
    rng = np.random.default_rng(0)
    spreads = np.array([[1.0, 1.1, 2.0, 2.0], [1.0, 1.5, 1.6, 4.0], [0.5, 0.5, 0.55, 0.6], [2.0, 1.0, 3.0, 1.0]])
    samples = known_spreads(rng, spreads)
    calibration = known_spreads(rng, rng.uniform(0.5, 3.0, size=(40, 4)))
    base = lengths_under(samples, calibration)
    # H_u - H_1 = 2 ln(spread_u / spread_1) (two dims): row 3 steps by 2 ln 1.1 = 0.19, then 2 ln 1.2 = 0.36 > 0.3
    assert base["growth"] == [2, 1, 3, 2]
    assert len(set(base["quantile"])) > 1
    scaled = lengths_under(10.0 * samples, 10.0 * calibration)

    def with_constant(x: th.Tensor) -> th.Tensor:
        return th.cat([x, th.full_like(x[..., :1], 0.3)], dim=-1)

    constant = lengths_under(with_constant(samples), with_constant(calibration))
    for rule in ("growth", "quantile"):
        assert scaled[rule] == base[rule] and constant[rule] == base[rule], rule
    assert scaled["threshold"] != base["threshold"] and constant["threshold"] != base["threshold"]


def test_deterministic_noise_is_a_function_of_the_history_alone():
    obs = th.randn(3, 2, 4, generator=th.Generator().manual_seed(0))
    act = th.randn(3, 2, 1, generator=th.Generator().manual_seed(1))
    noise = history_noise(obs, act, 32, 5)
    assert noise.shape == (3, 32, 5, 1)
    assert th.equal(history_noise(obs[1:2], act[1:2], 32, 5)[0], noise[1])  # alone = in a batch
    assert th.equal(history_noise(obs[[2, 0]], act[[2, 0]], 32, 5), noise[[2, 0]])  # any order
    assert not th.equal(noise[0], noise[1])  # two histories, two independent draws
    changed = act.clone()
    changed[0, 0, 0] += 1e-3
    assert not th.equal(history_noise(obs, changed, 32, 5)[0], noise[0])  # the past actions count
    # independent standard normal draws: over 3 histories × 160 numbers, mean ~0 and SD ~1
    assert abs(float(noise.mean())) < 0.15 and abs(float(noise.std()) - 1.0) < 0.1


def quantile_model(**kwargs) -> UA2C:
    return UA2C("MlpPolicy", "Pendulum-v1", chunk_size=4, history_len=3, execution_rule="quantile",
                **{"seed": 0, **FAST, **kwargs})


def test_learn_calibrates_the_quantile_rule_from_the_buffer_and_a_load_acts_with_it(tmp_path):
    model = quantile_model(entropy_quantile=0.5)
    assert model.policy.needs_calibration
    model.learn(100)  # the first policy plan after the random warm-up calibrates from the buffer
    thresholds = model.policy.calibrated_thresholds.clone()
    assert not model.policy.needs_calibration and thresholds.shape == (4,)
    model.save(tmp_path / "q.zip")
    loaded = UA2C.load(tmp_path / "q.zip")
    assert loaded.execution == loaded.policy.execution == ExecutionRule("quantile", entropy_quantile=0.5)
    assert th.equal(loaded.policy.calibrated_thresholds, thresholds)
    obs = np.array([[0.3, -0.9, 0.4], [1.0, 0.0, -2.0]], dtype=np.float32)
    state_a = state_b = None
    for _ in range(6):
        a, state_a = model.predict(obs, state=state_a, deterministic=True)
        b, state_b = loaded.predict(obs, state=state_b, deterministic=True)
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(model.policy.last_plan_lengths, loaded.policy.last_plan_lengths)


def _random_episode(seed: int, steps: int = 40) -> dict[str, np.ndarray]:
    env = gym.make("Pendulum-v1")
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    episode = {"observations": [obs], "actions": [], "rewards": [], "terminations": [], "truncations": []}
    for _ in range(steps):
        action = env.action_space.sample()
        obs, reward, terminated, truncated, _ = env.step(action)
        for key, value in zip(("observations", "actions", "rewards", "terminations", "truncations"),
                              (obs, action, reward, terminated, truncated), strict=True):
            episode[key].append(value)
    return {k: np.asarray(v) for k, v in episode.items()}


def test_calibration_on_held_out_episodes_leaves_the_replay_buffer_alone():
    # the same episode in the buffer or held out, the same seed: the same draws and thresholds
    episode = _random_episode(seed=1)
    in_buffer = quantile_model(entropy_quantile=0.5, learning_starts=0, seed=4)
    in_buffer.add_offline_episodes([episode])
    expected = in_buffer.calibrate_execution(n_histories=30, n_samples=32)
    held_out = quantile_model(entropy_quantile=0.5, learning_starts=0, seed=4)
    entropy = held_out.calibrate_execution(n_histories=30, n_samples=32, episodes=[episode])
    np.testing.assert_array_equal(entropy, expected)
    np.testing.assert_array_equal(held_out.policy.calibrated_thresholds.numpy(),
                                  in_buffer.policy.calibrated_thresholds.numpy())
    assert held_out.replay_buffer.n_samples() == (0, 0)
    with pytest.raises(ValueError, match="episodes holds no steps"):
        held_out.calibrate_execution(episodes=[])


def test_calibration_sets_the_quantile_of_the_measured_entropies():
    model = quantile_model(entropy_quantile=0.25, learning_starts=0)
    model.add_offline_episodes([_random_episode(seed=0)])
    entropy = model.calibrate_execution(n_histories=50, n_samples=64)
    assert entropy.shape == (50, 4)
    np.testing.assert_allclose(model.policy.calibrated_thresholds.numpy(), np.quantile(entropy, 0.25, axis=0),
                               rtol=1e-5)


def test_execution_rules_refuse_bad_input_naming_the_parameter():
    with pytest.raises(ValueError, match=r"execution_rule \(ExecutionRule.rule\) must be one of"):
        UA2C("MlpPolicy", "Pendulum-v1", execution_rule="entropy")
    with pytest.raises(ValueError, match="entropy_quantile must be a number in \\[0, 1\\]"):
        quantile_model(entropy_quantile=1.5)
    with pytest.raises(ValueError, match="entropy_growth must be a finite number >= 0"):
        UA2C("MlpPolicy", "Pendulum-v1", execution_rule="growth", entropy_growth=-0.1)
    with pytest.raises(ValueError, match="entropy_growth applies to execution_rule='growth' only"):
        UA2C("MlpPolicy", "Pendulum-v1", entropy_growth=0.5)
    with pytest.raises(ValueError, match="entropy_threshold applies to execution_rule='threshold' only"):
        quantile_model(entropy_threshold=1.0)
    model = quantile_model()
    with pytest.raises(ValueError, match="calibrate_execution needs histories in the replay buffer"):
        model.calibrate_execution()
    with pytest.raises(ValueError, match="n_histories"):
        model.calibrate_execution(n_histories=1)
    with pytest.raises(RuntimeError, match="calibrate_execution"):
        model.predict(np.zeros(3, dtype=np.float32))
    with pytest.raises(ValueError, match="execution must be an ExecutionRule"):
        model.set_execution_rule({"rule": "growth"})
    model.set_execution_rule(ExecutionRule("growth", entropy_growth=0.2))
    assert (model.execution.rule, model.policy.execution.growth, model.policy.calibrated_thresholds) == ("growth", 0.2, None)
    with pytest.raises(ValueError, match="calibration applies to execution_rule='quantile'"):
        model.policy.calibrate_entropy_thresholds(th.zeros(4, 3, 3), th.zeros(4, 3, 1))
