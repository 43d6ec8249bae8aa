"""Each hyperparameter declared once: the execution rule as one checked object (:class:`ExecutionRule`),
one default per argument, structural arguments required below the model, and checkpoints of the
layout before the rule was one object."""

import dataclasses
import inspect
import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch as th
from torch import nn
from ua2c_helpers import ACT, FAST, OBS, rollout_actions

from sb3_ua2c import UA2C, UA2CPolicy
from sb3_ua2c.actors import VelocityField
from sb3_ua2c.buffers import ChunkReplayBuffer
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.critics import ChunkCritics, MLPChunkCritics, critic_defaults
from sb3_ua2c.defaults import defaults as resolved_defaults

REPO = Path(__file__).resolve().parents[2]
#: the Phase-1 checkpoint shipped in rl-trained-agents until 2026-12-07 (flat critic arguments, the
#: execution rule as separate fields): the earlier layout, kept as a test fixture
EARLIER = REPO / "tests" / "data" / "earlier_layout_checkpoint.zip"
#: the Phase-1 checkpoint shipped in rl-trained-agents now
SHIPPED = REPO / "rl-trained-agents" / "ua2c" / "MixedTraffic-v0_1" / "MixedTraffic-v0.zip"
#: UA2C's arguments that make up the execution rule, by the field of ExecutionRule they fill
RULE_ARGUMENTS = {
    "execution_rule": "rule",
    "entropy_threshold": "entropy_threshold",
    "target_plan_length": "target_plan_length",
    "entropy_quantile": "entropy_quantile",
    "entropy_growth": "entropy_growth",
}


def defaults(function) -> dict:
    return {n: p.default for n, p in inspect.signature(function).parameters.items()}


# ------------------------------------------------------------------------------ ExecutionRule
@pytest.mark.parametrize(
    ("fields", "match"),
    [
        (dict(rule="entropy"), r"execution_rule \(ExecutionRule.rule\) must be one of"),
        (dict(rule=None), r"ExecutionRule.rule"),
        (dict(entropy_threshold="Auto"), "entropy_threshold must be a number or 'auto', got 'Auto'"),
        (dict(entropy_threshold=math.nan), "entropy_threshold must be a number or 'auto', got nan"),
        (dict(entropy_threshold=True), "entropy_threshold must be a number or 'auto', got True"),
        (dict(entropy_threshold=-math.inf), "entropy_threshold must not be -inf"),
        (dict(entropy_threshold="auto", target_plan_length="3"), "target_plan_length must be a number or None"),
        (dict(entropy_threshold="auto", target_plan_length=0.99), r"target_plan_length must be a number in \[1, "),
        (dict(target_plan_length=2.0), "target_plan_length applies to entropy_threshold='auto' only"),
        (dict(rule="quantile", entropy_quantile=1.01), r"entropy_quantile must be a number in \[0, 1\], got 1.01"),
        (dict(rule="quantile", entropy_quantile=-0.1), r"entropy_quantile must be a number in \[0, 1\]"),
        (dict(rule="growth", entropy_growth=-0.5), "entropy_growth must be a finite number >= 0, got -0.5"),
        (dict(rule="growth", entropy_growth=math.inf), "entropy_growth must be a finite number >= 0, got inf"),
        (dict(entropy_quantile=0.5), "entropy_quantile applies to execution_rule='quantile' only"),
        (dict(entropy_growth=0.5), "entropy_growth applies to execution_rule='growth' only"),
        (dict(rule="growth", entropy_threshold=1.0), "entropy_threshold applies to execution_rule='threshold' only"),
        (dict(rule="quantile", entropy_threshold="auto"), "entropy_threshold applies to execution_rule="),
    ],
)
def test_a_bad_field_of_the_rule_raises_naming_it(fields, match):
    with pytest.raises(ValueError, match=match):
        ExecutionRule(**fields)
    arguments = {name: fields[field] for name, field in RULE_ARGUMENTS.items() if field in fields}
    if None in arguments.values():
        return  # UA2C's None stands for the rule's default
    with pytest.raises(ValueError, match=match):
        UA2C("MlpPolicy", "Pendulum-v1", **arguments)


def test_a_good_rule_is_kept_as_given_and_frozen():
    rule = ExecutionRule("quantile", entropy_quantile=0.5)
    assert (rule.rule, rule.quantile, rule.growth, rule.auto) == ("quantile", 0.5, 0.5, False)
    assert ExecutionRule(entropy_threshold="auto").auto and not ExecutionRule().auto
    assert ExecutionRule("growth").growth == 0.5 and ExecutionRule().quantile == 0.75  # the documented defaults
    with pytest.raises(dataclasses.FrozenInstanceError):
        rule.entropy_quantile = 0.9  # type: ignore[misc]
    ExecutionRule(entropy_threshold="auto", target_plan_length=5).check_chunk_size(5)
    with pytest.raises(ValueError, match=r"target_plan_length must be a number in \[1, chunk_size=4\], got 5"):
        ExecutionRule(entropy_threshold="auto", target_plan_length=5).check_chunk_size(4)


def test_the_model_builds_one_rule_and_the_policy_holds_it():
    model = UA2C("MlpPolicy", "Pendulum-v1", execution_rule="growth", entropy_growth=0.25, **FAST)
    assert model.execution is model.policy.execution
    assert model.execution == ExecutionRule("growth", entropy_growth=0.25)
    for name in RULE_ARGUMENTS:  # the five arguments live in the rule only
        assert name not in vars(model) and name not in vars(model.policy)
    fixed = dataclasses.replace(model.execution, rule="threshold", entropy_growth=None, entropy_threshold=math.inf)
    model.set_execution_rule(fixed)
    assert model.execution is model.policy.execution is fixed
    assert not hasattr(model, "set_entropy_threshold") and not hasattr(model.policy, "set_entropy_threshold")


@pytest.mark.parametrize("key", ["execution", "entropy_threshold", "chunk_size"])
def test_policy_kwargs_may_not_set_what_the_model_passes(key):
    with pytest.raises(ValueError, match=rf"policy_kwargs\['{key}'\] is set by UA2C's own argument"):
        UA2C("MlpPolicy", "Pendulum-v1", policy_kwargs={key: 1})


# ------------------------------------------------------------------------------ one default each
def test_the_rule_defaults_are_the_models():
    model = defaults(UA2C.__init__)
    rule = {f.name: f.default for f in dataclasses.fields(ExecutionRule)}
    assert {name: model[name] for name in RULE_ARGUMENTS} == dict.fromkeys(RULE_ARGUMENTS)  # None: the rule's
    assert rule == {"rule": "threshold", "entropy_threshold": 0.0, "target_plan_length": None,
                    "entropy_quantile": None, "entropy_growth": None, "ensemble_decay": 0.01}
    resolved = resolved_defaults()
    assert {name: resolved[name] for name in RULE_ARGUMENTS} == {name: rule[f] for name, f in RULE_ARGUMENTS.items()}
    assert UA2C("MlpPolicy", "Pendulum-v1", **FAST).execution == ExecutionRule()


def test_the_model_takes_an_execution_rule():
    rule = ExecutionRule("growth", entropy_growth=0.2)
    model = UA2C("MlpPolicy", "Pendulum-v1", execution_rule=rule, **FAST)
    assert model.execution is model.policy.execution is rule
    for name in ("entropy_threshold", "target_plan_length", "entropy_quantile", "entropy_growth"):
        with pytest.raises(ValueError, match=rf"{name}=0.5 cannot be given with execution_rule=ExecutionRule"):
            UA2C("MlpPolicy", "Pendulum-v1", execution_rule=rule, **{name: 0.5}, **FAST)
    flat = UA2C("MlpPolicy", "Pendulum-v1", execution_rule="growth", entropy_growth=0.2, **FAST)
    assert flat.execution == rule


def test_structural_arguments_have_no_default_below_the_model():
    empty = inspect.Parameter.empty
    policy, buffer = defaults(UA2CPolicy.__init__), defaults(ChunkReplayBuffer.__init__)
    assert [policy[n] for n in ("chunk_size", "history_len", "flow_steps", "n_candidates")] == [empty] * 4
    assert [buffer[n] for n in ("chunk_size", "history_len", "offline_ratio", "online_targets")] == [empty] * 4
    # a critic's shared arguments come from the policy; its own have their one default in its signature
    critics = defaults(ChunkCritics.__init__)
    assert [critics[n] for n in ("n_critics", "activation_fn")] == [empty] * 2
    assert [critics[n] for n in ("embed_dim", "n_layers", "n_heads", "ff_dim")] == [32, 1, 1, 64]
    mlp = defaults(MLPChunkCritics.__init__)
    assert [mlp[n] for n in ("n_critics", "activation_fn")] == [empty] * 2
    assert [mlp[n] for n in ("net_arch", "layer_norm")] == [(256, 256), True]
    assert defaults(VelocityField.__init__)["activation_fn"] is empty
    with pytest.raises(TypeError, match="chunk_size"):
        ChunkReplayBuffer(32, OBS, ACT, history_len=2, offline_ratio=0.5, online_targets="auto")


def test_the_arguments_the_model_shares_have_its_defaults():
    model, policy = defaults(UA2C.__init__), defaults(UA2CPolicy.__init__)
    shared = ("discrete_action_dims", "discrete_entropy", "commit_discrete")
    assert {n: policy[n] for n in shared} == {n: model[n] for n in shared} == {
        "discrete_action_dims": None, "discrete_entropy": True, "commit_discrete": False}
    assert policy["execution"] is None  # ExecutionRule(), the model's defaults (above)
    # the critics the policy builds by default: the policy's widths (32, 64), not others
    built = UA2C("MlpPolicy", "Pendulum-v1", **{k: v for k, v in FAST.items() if k != "policy_kwargs"}).policy
    assert policy["critic_kwargs"] is None and built.critic_kwargs == critic_defaults("transformer")
    assert critic_defaults("transformer") == {"embed_dim": 32, "n_layers": 1, "n_heads": 1, "ff_dim": 64}
    want = ChunkCritics(4 * 3, 5, 1, n_critics=2, activation_fn=nn.SiLU, embed_dim=32, n_layers=1, n_heads=1, ff_dim=64)
    assert [p.shape for p in built.critic.parameters()] == [p.shape for p in want.parameters()]
    assert built.activation_fn is nn.SiLU


# ------------------------------------------------------------------------------ earlier checkpoints
def as_legacy_zip(path: Path, out: Path) -> None:
    """Rewrite a saved model as the earlier layout saved it: the five rule arguments as attributes."""
    with zipfile.ZipFile(path) as src:
        data = json.loads(src.read("data"))
        files = {name: src.read(name) for name in src.namelist()}
    assert ":serialized:" in data.pop("execution")
    rule = UA2C.load(path).execution
    data.update({name: getattr(rule, field) for name, field in RULE_ARGUMENTS.items()})
    files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(out, "w") as dst:
        for name, content in files.items():
            dst.writestr(name, content)


def test_a_model_saved_with_the_rule_as_five_attributes_loads_and_acts_the_same(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, entropy_threshold="auto", target_plan_length=2.5, **FAST)
    model.learn(150)
    model.save(tmp_path / "new.zip")
    as_legacy_zip(tmp_path / "new.zip", tmp_path / "old.zip")
    with zipfile.ZipFile(tmp_path / "old.zip") as old:
        saved = json.loads(old.read("data"))
    assert "execution" not in saved and saved["entropy_threshold"] == "auto" and saved["target_plan_length"] == 2.5
    loaded = UA2C.load(tmp_path / "old.zip")
    assert loaded.execution == loaded.policy.execution == ExecutionRule(entropy_threshold="auto", target_plan_length=2.5)
    assert "entropy_threshold" not in vars(loaded)
    np.testing.assert_array_equal(rollout_actions(loaded), rollout_actions(model))
    # the legacy names given to load override the saved rule field by field
    assert UA2C.load(tmp_path / "old.zip", entropy_threshold=1.0, target_plan_length=None).execution == ExecutionRule(
        entropy_threshold=1.0)


def test_a_policy_saved_with_the_rule_as_five_arguments_loads_and_acts_the_same(tmp_path):
    model = UA2C("MlpPolicy", "Pendulum-v1", seed=0, execution_rule="growth", entropy_growth=0.3, **FAST)
    model.learn(120)
    model.policy.save(tmp_path / "policy.pt")
    saved = th.load(tmp_path / "policy.pt", weights_only=False)
    rule = saved["data"].pop("execution")
    saved["data"].update({name: getattr(rule, field) for name, field in RULE_ARGUMENTS.items()})
    th.save(saved, tmp_path / "old.pt")
    loaded = UA2CPolicy.load(tmp_path / "old.pt")
    assert loaded.execution == ExecutionRule("growth", entropy_growth=0.3)
    np.testing.assert_array_equal(rollout_actions(loaded), rollout_actions(model.policy))


def test_a_checkpoint_of_the_earlier_layout_loads():
    with zipfile.ZipFile(EARLIER) as ckpt:
        saved = json.loads(ckpt.read("data"))
    assert "execution" not in saved and saved["entropy_threshold"] == 0.0  # the earlier layout
    model = UA2C.load(EARLIER, device="cpu")
    assert model.execution == model.policy.execution == ExecutionRule()
    # its flat critic arguments: critic_kwargs of the Transformer; the same networks when given as now
    assert saved["policy_kwargs"] == {"critic_embed_dim": 64, "critic_n_layers": 1, "net_arch": [256, 256, 256]}
    assert model.policy.critic_kwargs == {"embed_dim": 64, "n_layers": 1, "n_heads": 1, "ff_dim": 64}
    now = {"net_arch": [256, 256, 256], "critic_kwargs": {"embed_dim": 64, "n_layers": 1}}
    assert UA2C.load(EARLIER, device="cpu", policy_kwargs=now).policy.critic_kwargs == model.policy.critic_kwargs
    with pytest.raises(ValueError, match="policy kwargs"):
        UA2C.load(EARLIER, device="cpu", policy_kwargs={**now, "critic_kwargs": {"embed_dim": 32}})
    assert (model.chunk_size, model.history_len) == (saved["chunk_size"], saved["history_len"])


def test_the_shipped_checkpoint_carries_the_defaults():
    with zipfile.ZipFile(SHIPPED) as ckpt:
        saved = json.loads(ckpt.read("data"))
    assert "execution" in saved and "entropy_threshold" not in saved  # this release's layout
    model = UA2C.load(SHIPPED, device="cpu")
    expected = resolved_defaults()
    assert (model.flow_steps, model.policy.net_arch, model.policy.n_elite) == (
        expected["flow_steps"], expected["policy_kwargs"]["net_arch"], expected["policy_kwargs"]["n_elite"])
