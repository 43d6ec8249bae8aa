"""One home per default: :func:`sb3_ua2c.defaults.defaults` reads every hyperparameter's default from
where it is declared, and no other line of the algorithm, the research harnesses or the zoo's UA2C
files writes a default value again.

The scan: for every hyperparameter of ``defaults()`` (UA2C's arguments, ``policy_kwargs`` and every
critic class's own arguments), a Python source is parsed and each place that gives that name a literal
is compared with the default: a keyword argument ``name=LIT`` (also in ``dict(...)``), a parameter
default ``name: T = LIT``, an annotated or plain assignment ``name = LIT``, a dict entry ``"name": LIT``;
a YAML file's ``name: LIT`` lines and its ``policy_kwargs: "dict(...)"`` strings likewise. Comments and
docstrings are never read. A literal equal to the default is a second home and fails the test unless
its line carries the marker :data:`MARKER` followed by the reason, e.g.
``"n_candidates": 32,  # same as default: the paper's S, stated so the preset stays the paper's``.
The declarations themselves (:data:`DECLARATIONS`) are skipped. Defaults of ``None`` and the SB3
plumbing arguments (:data:`NOT_SCANNED`) are not scanned.
"""

from __future__ import annotations

import ast
import math
import re
from pathlib import Path
from typing import Any

import pytest
import torch as th
import yaml

from sb3_ua2c import UA2C
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.critics import CRITICS, critic_defaults
from sb3_ua2c.defaults import defaults
from sb3_ua2c.options import OPTIONS
from sb3_ua2c.registry import own_defaults

ROOT = Path(__file__).resolve().parents[2]
#: the comment that allows a literal equal to a default; a reason must follow it
MARKER = "# same as default:"
#: SB3's plumbing arguments: not hyperparameters of the algorithm (``verbose=0`` is everywhere)
NOT_SCANNED = {"verbose", "device", "seed", "tensorboard_log", "stats_window_size", "normalize_images"}
#: where a default is declared: ``(file, qualified name of the function or class)``
DECLARATIONS = {
    ("sb3_ua2c/ua2c.py", "UA2C.__init__"),
    ("sb3_ua2c/policies.py", "UA2CPolicy.__init__"),
    ("sb3_ua2c/config.py", "ExecutionRule"),
    ("sb3_ua2c/critics/transformer.py", "ChunkCritics.__init__"),
    ("sb3_ua2c/critics/mlp.py", "MLPChunkCritics.__init__"),
    ("sb3_ua2c/targets/in_sample.py", "InSampleTarget.__init__"),
    ("sb3_ua2c/extraction.py", "AdvantageWeightedExtraction.__init__"),
    ("sb3_ua2c/exploration.py", "SoftmaxExploration.__init__"),
}
#: a constructor argument kept under another attribute name (``model.critic_target`` is SB3's target critics)
ATTRIBUTE = {"critic_target": "critic_target_name"}


# ---------------------------------------------------------------------------- (a) the defaults
def test_defaults_by_hand():
    out = defaults()
    assert (out["chunk_size"], out["history_len"], out["flow_steps"], out["n_candidates"]) == (5, 4, 5, 32)
    assert (out["q_weight"], out["gradient_steps"], out["execution_rule"], out["entropy_threshold"]) == (
        0.3, 1, "threshold", 0.0)
    assert out["target_plan_length"] is None and out["entropy_quantile"] is None
    policy = out["policy_kwargs"]
    assert (policy["n_elite"], policy["net_arch"], policy["actor_type"], policy["critic_arch"]) == (
        8, [256, 256], "flow", "transformer")
    assert policy["critic_kwargs"] == {"embed_dim": 32, "n_layers": 1, "n_heads": 1, "ff_dim": 64}
    assert critic_defaults("mlp") == {"net_arch": (256, 256), "layer_norm": True}
    assert (out["critic_target"], out["actor_extraction"], out["exploration"]) == ("candidates", "value_term", "softmax")
    assert (out["critic_target_kwargs"], out["actor_extraction_kwargs"], out["exploration_kwargs"]) == (
        {}, {}, {"temperature": 1.0})
    assert own_defaults(OPTIONS["critic_target"]["in_sample"]) == {
        "expectile": 0.7, "net_arch": (256, 256), "layer_norm": True}
    assert own_defaults(OPTIONS["actor_extraction"]["awr"]) == {"temperature": 3.0, "max_weight": 100.0}
    assert own_defaults(OPTIONS["exploration"]["softmax"]) == {"temperature": 1.0}
    out["policy_kwargs"]["n_elite"] = 1
    assert defaults()["policy_kwargs"]["n_elite"] == 8  # a fresh dict


def test_defaults_are_what_a_model_built_without_arguments_has():
    out = defaults()
    model = UA2C("MlpPolicy", "Pendulum-v1")
    skipped = {"policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "device", "execution_rule",
               "entropy_threshold", "target_plan_length", "entropy_quantile", "entropy_growth", "train_freq",
               "stats_window_size"}
    for name, value in out.items():
        if name not in skipped:
            assert getattr(model, ATTRIBUTE.get(name, name)) == value, name
    assert model.train_freq.frequency == out["train_freq"]
    assert model.replay_buffer.offline_ratio == out["offline_ratio"]
    assert model.execution == ExecutionRule(out["execution_rule"], out["entropy_threshold"])
    policy = model.policy
    for name, value in out["policy_kwargs"].items():
        if name not in ("critic_kwargs", "optimizer_kwargs"):
            assert getattr(policy, name) == value, name
    critic = policy.critic
    assert critic.embed_dim == out["policy_kwargs"]["critic_kwargs"]["embed_dim"]
    assert len(critic.blocks) == out["policy_kwargs"]["critic_kwargs"]["n_layers"]
    assert critic.blocks[0].ff1.weight.shape[-1] == out["policy_kwargs"]["critic_kwargs"]["ff_dim"]


# ---------------------------------------------------------------------------- (b) the scan
def scanned_defaults() -> dict[str, list[Any]]:
    """``{name: [default, ...]}`` of every hyperparameter scanned (a name may have a default per critic class)."""
    out = defaults()
    policy = out.pop("policy_kwargs")
    policy.pop("critic_kwargs")
    names: dict[str, list[Any]] = {}
    plugins = [own_defaults(cls) for registry in OPTIONS.values() for cls in registry.values()]
    for table in (out, policy, *(critic_defaults(arch) for arch in CRITICS), *plugins):
        for name, value in table.items():
            if name not in NOT_SCANNED and value is not None and not isinstance(value, type):
                names.setdefault(name, []).append(value)
    return names


def _same(value: Any, default: Any) -> bool:
    """``value == default`` with ``bool`` kept apart from numbers and lists equal to tuples."""
    if isinstance(value, bool) != isinstance(default, bool):
        return False
    if isinstance(value, list | tuple) and isinstance(default, list | tuple):
        return list(value) == list(default)
    if isinstance(value, float | int) and isinstance(default, float | int):
        return value == default or (math.isnan(value) and math.isnan(default))
    return type(value) is type(default) and value == default


def _literal(node: ast.AST) -> Any:
    try:
        return ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return _NOT_LITERAL


_NOT_LITERAL = object()


def _marked(lines: list[str], node: ast.AST) -> bool:
    """The node's lines carry the marker with a reason."""
    text = " ".join(lines[node.lineno - 1 : node.end_lineno])
    at = text.find(MARKER)
    return at >= 0 and bool(text[at + len(MARKER) :].strip())


def _named_literals(tree: ast.AST) -> list[tuple[str, ast.AST, str]]:
    """``(name, value node, qualified name of the enclosing function/class)`` of every named literal."""
    found: list[tuple[str, ast.AST, str]] = []

    def visit(node: ast.AST, scope: str) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            inner = f"{scope}.{node.name}" if scope else node.name
            if not isinstance(node, ast.ClassDef):
                args = node.args
                positional = [*args.posonlyargs, *args.args]
                pairs = list(zip(positional[len(positional) - len(args.defaults) :], args.defaults, strict=True))
                pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True) if d is not None]
                found.extend((a.arg, d, inner) for a, d in pairs)
            for child in ast.iter_child_nodes(node):
                visit(child, inner)
            return
        if isinstance(node, ast.Call):
            found.extend((kw.arg, kw.value, scope) for kw in node.keywords if kw.arg)
        elif isinstance(node, ast.Dict):
            found.extend((k.value, v, scope) for k, v in zip(node.keys, node.values, strict=True)
                         if isinstance(k, ast.Constant) and isinstance(k.value, str))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None:
            found.append((node.target.id, node.value, scope))
        elif isinstance(node, ast.Assign):
            found.extend((t.id, node.value, scope) for t in node.targets if isinstance(t, ast.Name))
        for child in ast.iter_child_nodes(node):
            visit(child, scope)

    visit(tree, "")
    return found


def scan_python(source: str, names: dict[str, list[Any]], where: str = "<source>") -> list[str]:
    """
    The second homes of defaults in a Python source.

    :param source: the module's text
    :param names: ``{hyperparameter: [defaults]}``
    :param where: the file, relative to the repository (declarations are skipped by it)
    :return: ``"file:line: name=value"`` per unmarked literal equal to a default
    """
    lines = source.splitlines()
    hits = []
    for name, node, scope in _named_literals(ast.parse(source)):
        if name not in names or (where, scope) in DECLARATIONS:
            continue
        value = _literal(node)
        if value is not _NOT_LITERAL and any(_same(value, d) for d in names[name]) and not _marked(lines, node):
            hits.append(f"{where}:{node.lineno}: {name}={value!r}")
    return hits


_YAML_KEY = re.compile(r"^\s*(?:-\s+)?([A-Za-z_]\w*):\s*(.+?)\s*$")


def scan_yaml(text: str, names: dict[str, list[Any]], where: str = "<yaml>") -> list[str]:
    """The second homes of defaults in an rl-zoo YAML file (its ``name: value`` lines and ``dict(...)`` strings)."""
    hits = []
    for number, line in enumerate(text.splitlines(), start=1):
        body, _, comment = line.partition(" #") if not line.lstrip().startswith("#") else ("", "", "")
        match = _YAML_KEY.match(body)
        if not match:
            continue
        marked = f"#{comment}".startswith(MARKER) and bool(f"#{comment}"[len(MARKER) :].strip())
        name, raw = match.groups()
        value = yaml.safe_load(raw) if raw else None
        if isinstance(value, str) and value.lstrip().startswith("dict("):
            inner = scan_python(value, names, where)
            hits += [f"{where}:{number}: {hit.split(': ', 1)[1]}" for hit in inner if not marked]
        elif name in names and any(_same(value, d) for d in names[name]) and not marked:
            hits.append(f"{where}:{number}: {name}={value!r}")
    return hits


#: the trees scanned; experiments/ and the zoo's files are not in every checkout
TREES = {"sb3_ua2c": "*.py", "experiments": "*.py", "zoo_configs": "ua2c*.yml"}
@pytest.mark.parametrize("tree", list(TREES))
def test_no_default_is_written_twice(tree):
    if not (ROOT / tree).is_dir():
        pytest.skip(f"no {tree}/ in this checkout")
    names = scanned_defaults()
    hits = []
    for path in sorted((ROOT / tree).rglob(TREES[tree])):
        where, text = str(path.relative_to(ROOT)), path.read_text(encoding="utf-8")
        hits += scan_yaml(text, names, where) if path.suffix == ".yml" else scan_python(text, names, where)
    assert not hits, (
        f"a default written again (take it from sb3_ua2c.defaults.defaults(), or mark the line with "
        f"'{MARKER} <why>'):\n" + "\n".join(hits)
    )


FAKE_PRESET = '''
"""A preset whose docstring says n_elite=8 (not read)."""
# a comment with n_elite=8 (not read)
FAST = {"n_elite": 8, "q_weight": 0.5, "chunk_size": 5}
PAPER = {
    "flow_steps": 5,  # same as default: stated so the preset keeps it when the default changes
    "flow_steps_note": 5,
}
def run(model_class, env, n_elite=8, learning_starts=1000, normalize_q: bool = True):
    return model_class("MlpPolicy", env, n_candidates=32, policy_kwargs=dict(n_elite=8, embed_dim=32))
'''


def test_the_scan_finds_a_default_written_again():
    names = scanned_defaults()
    hits = [hit.split(": ", 1)[1] for hit in scan_python(FAKE_PRESET, names)]
    assert hits == ["n_elite=8", "chunk_size=5", "n_elite=8", "learning_starts=1000", "normalize_q=True",
                    "n_candidates=32", "n_elite=8", "embed_dim=32"]
    # a marker without a reason does not count; a value other than the default is no hit
    assert scan_python('X = {"n_elite": 8}  # same as default:\n', names) == ["<source>:1: n_elite=8"]
    assert scan_python('X = {"n_elite": 1, "n_layers": True}\n', names) == []
    # the declarations themselves are skipped, the same text elsewhere is not
    declared = "class UA2C:\n    def __init__(self, chunk_size: int = 5):\n        pass\n"
    assert scan_python(declared, names, "sb3_ua2c/ua2c.py") == []
    assert scan_python(declared, names, "sb3_ua2c/presets.py") == ["sb3_ua2c/presets.py:2: chunk_size=5"]


def test_the_scan_reads_zoo_yaml():
    names = scanned_defaults()
    text = (
        "# n_elite: 8 in a comment\n"
        "Pendulum-v1:\n"
        "  flow_steps: 5\n"
        "  n_candidates: 32  # same as default: the paper's S\n"
        "  q_weight: 1.0\n"
        "  online_targets: auto\n"
        "  policy_kwargs: \"dict(n_elite=8, net_arch=[128, 128], critic_kwargs=dict(ff_dim=64))\"\n"
    )
    assert scan_yaml(text, names) == ["<yaml>:3: flow_steps=5", "<yaml>:6: online_targets='auto'",
                                      "<yaml>:7: n_elite=8", "<yaml>:7: ff_dim=64"]


def test_defaults_keep_their_types():
    out = defaults()
    assert isinstance(out["policy_kwargs"]["activation_fn"], type)
    assert out["policy_kwargs"]["optimizer_class"] is th.optim.Adam
