"""``bench_ua2c.py merge``: one ``learning --json`` record from runs split by seed and algorithm."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_ua2c.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_ua2c", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _part(path: Path, seeds, command: str, **returns) -> str:
    record = {**returns, "seeds": seeds, "steps": 20000, "eval_episodes": 10, "env": "Pendulum-v1",
              "ua2c_kwargs": {}, "torch": "2.13.0+cpu", "command": command, "date": "2026-12-07 18:00 UTC"}
    record["ua2c_mean_executed_length"] = [4.0 + s for s in seeds] if "ua2c" in returns else []
    path.write_text(json.dumps(record))
    return str(path)


def test_merge_orders_each_algorithm_by_seed(bench, tmp_path):
    a = _part(tmp_path / "a.json", [3, 4], "a", ua2c=[-3.0, -4.0], sac=[-30.0, -40.0])
    b = _part(tmp_path / "b.json", [0, 1, 2], "b", ua2c=[0.0, -1.0, -2.0])
    c = _part(tmp_path / "c.json", [2, 0, 1], "c", sac=[-20.0, 0.0, -10.0])  # SAC alone: its ua2c_kwargs are not read
    Path(c).write_text(Path(c).read_text().replace('"ua2c_kwargs": {}', '"ua2c_kwargs": {"ignored": 1}'))
    bench.merge([a, b, c], str(tmp_path / "all.json"))
    out = json.loads((tmp_path / "all.json").read_text())
    assert out["seeds"] == [0, 1, 2, 3, 4]
    assert out["ua2c"] == [0.0, -1.0, -2.0, -3.0, -4.0] and out["sac"] == [0.0, -10.0, -20.0, -30.0, -40.0]
    assert out["ua2c_mean_executed_length"] == [4.0, 5.0, 6.0, 7.0, 8.0]
    assert out["commands"] == ["a", "b", "c"] and out["steps"] == 20000


def test_merge_refuses_other_protocols_doubles_and_gaps(bench, tmp_path):
    a = _part(tmp_path / "a.json", [0], "a", ua2c=[0.0], sac=[1.0])
    other = tmp_path / "b.json"
    _part(other, [1], "b", ua2c=[0.0], sac=[1.0])
    other.write_text(other.read_text().replace('"steps": 20000', '"steps": 5000'))
    with pytest.raises(SystemExit, match=r"differs .* \['steps'\]"):
        bench.merge([a, str(other)], str(tmp_path / "out.json"))
    with pytest.raises(SystemExit, match="ua2c seed 0 is in more than one input"):
        bench.merge([a, a], str(tmp_path / "out.json"))
    kwargs = tmp_path / "k.json"
    _part(kwargs, [1], "k", ua2c=[0.0], sac=[1.0])
    kwargs.write_text(kwargs.read_text().replace('"ua2c_kwargs": {}', '"ua2c_kwargs": {"chunk_size": 1}'))
    with pytest.raises(SystemExit, match=r"differs .* \['ua2c_kwargs'\]"):
        bench.merge([a, str(kwargs)], str(tmp_path / "out.json"))
    gap = _part(tmp_path / "c.json", [1], "c", ua2c=[0.0])
    with pytest.raises(SystemExit, match="seeds missing"):
        bench.merge([a, gap], str(tmp_path / "out.json"))
