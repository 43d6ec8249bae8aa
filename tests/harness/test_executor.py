"""Executor of independent units (experiments.common.runner): local serial and process-pool paths."""

from __future__ import annotations

import json
import os

import executor_helpers as helpers
import pytest

from experiments.common.runner import (
    ProcessExecutor,
    RayExecutor,
    SerialExecutor,
    Unit,
    UnitsFailedError,
    make_executor,
    run_units,
)


def test_serial_runs_in_order_and_stores_results(tmp_path):
    units = [Unit(f"u{x}", helpers.square, {"x": x}, tmp_path / f"u{x}.json") for x in (3, 1, 2)]
    lines = []
    results = run_units(units, SerialExecutor(), printer=lines.append)
    assert [r.name for r in results] == ["u3", "u1", "u2"]
    assert [r.value["square"] for r in results] == [9, 1, 4]
    assert not any(r.skipped for r in results)
    assert json.loads((tmp_path / "u3.json").read_text()) == {"x": 3, "square": 9, "pid": os.getpid()}
    assert len(lines) == 3 and lines[0].startswith("[1/3] unit u3:")


def test_stored_units_are_skipped(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"stored": True}))
    # a unit that would fail if it ran: it must not run because its result exists
    units = [Unit("a", helpers.fail, {"message": "must not run"}, tmp_path / "a.json"),
             Unit("b", helpers.square, {"x": 4}, tmp_path / "b.json")]
    lines = []
    results = run_units(units, SerialExecutor(), printer=lines.append)
    assert results[0].skipped and results[0].value == {"stored": True} and results[0].wall_seconds == 0.0
    assert not results[1].skipped and results[1].value["square"] == 16
    assert lines[0] == "1 of 2 unit(s) already stored, 1 to run"


def test_a_failing_unit_does_not_stop_the_others(tmp_path):
    units = [Unit("bad", helpers.fail, {"message": "boom"}, tmp_path / "bad.json"),
             Unit("good", helpers.square, {"x": 5}, tmp_path / "good.json")]
    with pytest.raises(UnitsFailedError, match=r"1 unit\(s\) failed: \['bad'\]") as info:
        run_units(units, SerialExecutor(), printer=None)
    assert "ValueError: boom" in info.value.failures["bad"]
    assert not (tmp_path / "bad.json").exists()
    assert json.loads((tmp_path / "good.json").read_text())["square"] == 25


@pytest.mark.slow
def test_process_executor_gives_every_unit_a_fresh_process(tmp_path):
    units = [Unit(f"pid{i}", helpers.process_id) for i in range(2)] + [Unit("bad", helpers.fail, {"message": "child"})]
    with pytest.raises(UnitsFailedError) as info:
        run_units(units, ProcessExecutor(workers=1), printer=None)
    assert "ValueError: child" in info.value.failures["bad"]
    assert info.value.results[2] is None
    pids = [r.value for r in info.value.results[:2]]
    assert len(set(pids)) == 2 and os.getpid() not in pids  # one process per unit, none of them this one


@pytest.mark.slow
def test_process_executor_matches_serial_on_a_sumo_unit(tmp_path):
    units = [Unit(f"s{s}", helpers.sumo_episode, {"seed": s}) for s in (0, 1)]
    local = [r.value for r in run_units(units, ProcessExecutor(workers=2), printer=None)]
    serial = [r.value for r in run_units(units, SerialExecutor(), printer=None)]
    assert [v.pop("pid") for v in serial] == [os.getpid()] * 2 and os.getpid() not in [v.pop("pid") for v in local]
    assert local == serial
    assert [v["steps"] for v in local] == [10, 10]  # 2 s at 0.2 s per step
    assert local[0]["reward"] != local[1]["reward"]  # two different scenarios


def test_bad_input():
    with pytest.raises(ValueError, match="unique"):
        run_units([Unit("a", helpers.square, {"x": 1}), Unit("a", helpers.square, {"x": 2})], printer=None)
    with pytest.raises(ValueError, match="workers"):
        ProcessExecutor(0)
    with pytest.raises(ValueError, match="workers"):
        make_executor(workers=True)
    with pytest.raises(TypeError, match="Unit.fn"):
        Unit("a", "not a function")
    with pytest.raises(ValueError, match="Unit.name"):
        Unit("", helpers.square)
    with pytest.raises(ValueError, match="ray_address"):
        RayExecutor("")
    with pytest.raises(ValueError, match="serial"):
        make_executor(ray_address="auto", serial=True)


def test_make_executor():
    assert isinstance(make_executor(), ProcessExecutor) and make_executor(workers=3).workers == 3
    assert isinstance(make_executor(serial=True), SerialExecutor)
    ray = make_executor(ray_address="127.0.0.1:6379")
    assert isinstance(ray, RayExecutor) and ray.address == "127.0.0.1:6379"


def test_a_unit_in_a_worker_process_runs_one_torch_thread():
    """Two units of several torch threads each on two cores oversubscribe them: a unit owns one CPU."""
    from experiments.common.runner import ProcessExecutor

    [result] = run_units([Unit("threads", helpers.torch_threads)], ProcessExecutor(1))
    assert result.value == 1
