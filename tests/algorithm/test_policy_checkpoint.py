"""Policy-only checkpoints: ``policy.save`` / ``UA2CPolicy.load`` act exactly like the saved policy,
in this process and in a fresh one (SB3's "Exporting models")."""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from torch import nn
from ua2c_helpers import FAST, TINY

from sb3_ua2c import UA2C
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.policies import MlpPolicy, UA2CPolicy

TESTS_DIR = pathlib.Path(__file__).resolve().parent

#: run in a fresh interpreter: load the policy given as argv[1] and print its acting record as JSON
FRESH_PROCESS = """
import json, sys
import torch as th
th.set_num_threads(1)
sys.path[:0] = [sys.argv[2], sys.argv[3]]
from test_policy_checkpoint import acting_record
from sb3_ua2c.policies import UA2CPolicy
print(json.dumps(acting_record(UA2CPolicy.load(sys.argv[1]))))
"""


def acting_record(policy: UA2CPolicy) -> dict[str, list]:
    """
    Deterministic actions of ``policy``: one observation, a batch without state, SB3's ``forward``
    and a 14-step rollout of 3 envs carrying ``state`` (row 1 starts a new episode at step 6),
    with the executable lengths ``L_t`` of the plans, as JSON-able lists.
    """
    rng = np.random.default_rng(7)
    obs_dim = int(np.prod(policy.observation_space.shape))
    batch = rng.normal(size=(4, obs_dim)).astype(np.float32)
    record: dict[str, list] = {
        "single": policy.predict(batch[0], deterministic=True)[0].tolist(),
        "batch": policy.predict(batch, deterministic=True)[0].tolist(),
    }
    with th.inference_mode():
        record["forward"] = policy(th.as_tensor(batch), deterministic=True).tolist()
    stream = rng.normal(size=(14, 3, obs_dim)).astype(np.float32)
    state, actions, lengths = None, [], []
    for t, obs in enumerate(stream):
        start = np.array([t == 0, t in (0, 6), t == 0])
        action, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
        actions.append(action.tolist())
        lengths.append(state.plan_length.tolist())
    record["rollout"], record["plan_lengths"] = actions, lengths
    return record


def pendulum_policy() -> UA2CPolicy:
    """A UA2C policy trained for a few steps on Pendulum, acting with the elite mean of 2."""
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=4, history_len=3, entropy_threshold=1.32, **FAST)
    model.learn(100)
    model.set_n_elite(2)
    return model.policy


def lane_change_policy() -> UA2CPolicy:
    """A policy built by hand: categorical dim 1 (three lanes), asymmetric bounds, non-default networks."""
    return UA2CPolicy(
        spaces.Box(-5.0, 5.0, (4,), dtype=np.float32),
        spaces.Box(np.array([-3.0, -1.0], np.float32), np.array([2.0, 1.0], np.float32)),
        lambda _: 1e-3,
        chunk_size=3,
        history_len=2,
        flow_steps=2,
        n_candidates=6,
        execution=ExecutionRule(entropy_threshold=1.3),
        discrete_action_dims={1: [-1.0, 0.0, 1.0]},
        discrete_entropy=False,
        n_elite=3,
        commit_discrete=True,
        net_arch=[16, 8],
        critic_kwargs=dict(embed_dim=8, n_heads=2, ff_dim=16),
        n_critics=3,
        activation_fn=nn.Tanh,
        optimizer_class=th.optim.AdamW,
        optimizer_kwargs={"weight_decay": 0.1},
    )


@pytest.mark.parametrize("make_policy", [pendulum_policy, lane_change_policy])
def test_policy_checkpoint_acts_like_the_saved_policy(tmp_path, make_policy):
    th.manual_seed(0)
    policy = make_policy()
    expected = acting_record(policy)
    assert len({n for row in expected["plan_lengths"] for n in row}) > 1  # adaptive chunks: L_t varies
    policy.save(tmp_path / "policy.pt")

    for cls in (UA2CPolicy, MlpPolicy):
        loaded = cls.load(tmp_path / "policy.pt")
        assert type(loaded) is UA2CPolicy
        assert loaded._get_constructor_parameters() == policy._get_constructor_parameters()
        for name, tensor in policy.state_dict().items():
            assert th.equal(loaded.state_dict()[name], tensor), name
        assert acting_record(loaded) == expected

    fresh = subprocess.run(
        [sys.executable, "-c", FRESH_PROCESS, str(tmp_path / "policy.pt"), str(TESTS_DIR), str(TESTS_DIR.parent)],
        cwd=TESTS_DIR.parents[1],
        capture_output=True,
        text=True,
        check=True,
    )
    assert json.loads(fresh.stdout.splitlines()[-1]) == expected


def test_policy_checkpoint_keeps_the_acting_rule(tmp_path):
    """Every argument that shapes acting comes back with its value (not the constructor default)."""
    policy = lane_change_policy()
    policy.flow_steps = 5  # changed after construction, as UA2C.load(path, flow_steps=5) does
    policy.save(tmp_path / "policy.pt")
    loaded = UA2CPolicy.load(tmp_path / "policy.pt")
    got = {name: getattr(loaded, name) for name in ("chunk_size", "history_len", "flow_steps", "n_candidates")}
    assert got == {"chunk_size": 3, "history_len": 2, "flow_steps": 5, "n_candidates": 6}
    assert (loaded.execution, loaded.n_elite, loaded.discrete_dims) == (ExecutionRule(entropy_threshold=1.3), 3, {1: 3})
    assert (loaded.discrete_entropy, loaded.commit_discrete, loaded.net_arch) == (False, True, [16, 8])
    assert (loaded.n_critics, loaded.activation_fn) == (3, nn.Tanh)
    assert loaded.critic_kwargs == {"embed_dim": 8, "n_layers": 1, "n_heads": 2, "ff_dim": 16}
    assert loaded.action_space == policy.action_space and loaded.observation_space == policy.observation_space
    assert loaded.normalize_images is False
    assert isinstance(loaded.actor.optimizer, th.optim.AdamW)
    assert loaded.actor.optimizer.defaults["weight_decay"] == 0.1


def test_policy_checkpoint_of_fixed_chunks(tmp_path):
    """``entropy_threshold=inf`` (fixed chunk execution) survives the round trip."""
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, chunk_size=3, entropy_threshold=float("inf"), **FAST)
    model.policy.save(tmp_path / "policy.pt")
    loaded = UA2CPolicy.load(tmp_path / "policy.pt")
    assert loaded.execution.entropy_threshold == float("inf")
    assert acting_record(loaded) == acting_record(model.policy)


def test_normalize_images_must_be_false():
    box = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
    with pytest.raises(ValueError, match="normalize_images"):
        UA2CPolicy(box, box, lambda _: 1e-3, 3, 2, 2, 4, normalize_images=True, **TINY)
    with pytest.raises(ValueError, match="normalize_images"):
        UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs=dict(TINY, normalize_images=True))
