"""Run independent units of work in this process, in fresh local processes or as Ray tasks (``docs/peers.md``):
a unit whose ``result_file`` exists is skipped, and one that raises does not stop the others."""

from __future__ import annotations

import heapq
import json
import multiprocessing as mp
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_ua2c.checks import check_int
from sb3_ua2c.pipeline import write_json


@dataclass(frozen=True)
class Unit:
    """``fn(**kwargs)`` under a unique ``name``, its JSON result stored in ``result_file`` (if it exists: skipped)."""

    name: str
    fn: Callable[..., Any]
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    result_file: Path | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Unit.name must be a non-empty string, got {self.name!r}")
        if not callable(self.fn):
            raise TypeError(f"Unit.fn of {self.name!r} must be callable, got {type(self.fn).__name__}")
        if not isinstance(self.kwargs, Mapping):
            raise TypeError(f"Unit.kwargs of {self.name!r} must be a mapping, got {type(self.kwargs).__name__}")
        if self.result_file is not None:
            object.__setattr__(self, "result_file", Path(self.result_file))


@dataclass(frozen=True)
class UnitResult:
    """A unit's value (or stored result, ``skipped``) and the wall and CPU seconds of its run (0 when skipped)."""

    name: str
    value: Any
    skipped: bool
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0


class UnitsFailedError(RuntimeError):
    """Some units raised: ``failures`` maps their names to their tracebacks, ``results`` holds every unit's."""

    def __init__(self, failures: Mapping[str, str], results: Sequence[UnitResult | None] = ()) -> None:
        self.failures = dict(failures)
        self.results = list(results)
        details = "\n".join(f"--- {name}\n{tb}" for name, tb in self.failures.items())
        super().__init__(f"{len(self.failures)} unit(s) failed: {sorted(self.failures)}\n{details}")


def _call_unit_safely(unit: Unit) -> tuple[bool, Any, float, float]:
    """Run ``unit``: ``(True, value, wall seconds, CPU seconds)``, or ``(False, traceback, 0, 0)`` if it raised."""
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        value = unit.fn(**unit.kwargs)
    except Exception:  # reported by name once every unit has run
        return False, traceback.format_exc(), 0.0, 0.0
    return True, value, time.perf_counter() - wall, time.process_time() - cpu


def _call_unit_on_one_cpu(unit: Unit) -> tuple[bool, Any, float, float]:
    """:func:`_call_unit_safely` with torch on one thread: a unit owns one CPU (oversubscribed, torch's threads spin)."""
    with suppress(ImportError):  # a unit that does not use torch
        import torch

        torch.set_num_threads(1)
    return _call_unit_safely(unit)


class SerialExecutor:
    """Run units one after the other in this process."""

    def map(self, units: Sequence[Unit], on_done: Callable[[int, tuple], None]) -> None:
        for i, unit in enumerate(units):
            on_done(i, _call_unit_safely(unit))


class ProcessExecutor:
    """Run units in ``workers`` processes at a time, each unit in a fresh ``spawn``-ed process."""

    def __init__(self, workers: int = 1) -> None:
        check_int("workers", workers)
        self.workers = workers

    def map(self, units: Sequence[Unit], on_done: Callable[[int, tuple], None]) -> None:
        # one process per unit (Python >= 3.11; before, a worker runs several units one after another)
        fresh = {"max_tasks_per_child": 1} if sys.version_info >= (3, 11) else {}
        with ProcessPoolExecutor(max_workers=self.workers, mp_context=mp.get_context("spawn"), **fresh) as pool:
            futures = {pool.submit(_call_unit_on_one_cpu, unit): i for i, unit in enumerate(units)}
            for future in as_completed(futures):
                try:
                    outcome = future.result()
                except Exception:  # the worker died (e.g. a segfault): BrokenProcessPool
                    outcome = (False, traceback.format_exc(), 0.0, 0.0)
                on_done(futures[future], outcome)


class RayExecutor:
    """Run each unit as a Ray task with one CPU in its own process on the cluster at ``address``."""

    def __init__(self, address: str = "auto") -> None:
        if not isinstance(address, str) or not address:
            raise ValueError(f"ray_address must be a non-empty string, got {address!r}")
        self.address = address

    def map(self, units: Sequence[Unit], on_done: Callable[[int, tuple], None]) -> None:
        ray = _import_ray()
        with ray_session(None if ray.is_initialized() else self.address):  # within a session: its connection
            task = ray.remote(num_cpus=1, max_calls=1)(_call_unit_on_one_cpu)
            refs = {task.remote(unit): i for i, unit in enumerate(units)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    try:
                        outcome = ray.get(ref)
                    except Exception:  # the worker died or the task could not be scheduled
                        outcome = (False, traceback.format_exc(), 0.0, 0.0)
                    on_done(refs[ref], outcome)


Executor = SerialExecutor | ProcessExecutor | RayExecutor


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ValueError('--ray-address needs ray: pip install "sb3-ua2c[peers]"') from exc
    return ray


@contextmanager
def ray_session(address: str | None) -> Iterator[None]:
    """One connection to the Ray cluster at ``address`` for several :func:`run_units` calls (nothing for ``None``)."""
    if address is None:
        yield
        return
    ray = _import_ray()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(address=address, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


def make_executor(workers: int = 1, ray_address: str | None = None, serial: bool = False) -> Executor:
    """Ray when ``ray_address`` is given, else ``workers`` local processes, or this process with ``serial``."""
    check_int("workers", workers)
    if ray_address is not None:
        if serial:
            raise ValueError("serial=True runs units in this process: it cannot be combined with ray_address")
        return RayExecutor(ray_address)
    return SerialExecutor() if serial else ProcessExecutor(workers)


def list_schedule_seconds(durations: Sequence[float], workers: int) -> float:
    """When the last of ``durations`` ends, each unit starting on the first of ``workers`` workers that is free."""
    check_int("workers", workers)
    free = [0.0] * min(workers, max(len(durations), 1))
    for seconds in durations:
        heapq.heappush(free, heapq.heappop(free) + seconds)
    return max(free)


def run_units(units: Sequence[Unit], executor: Executor | None = None,
              printer: Callable[[str], Any] | None = print) -> list[UnitResult]:
    """Run ``units`` (but the stored ones) on ``executor``; their results in order, or :class:`UnitsFailedError`."""
    names = [unit.name for unit in units]
    if len(set(names)) != len(names):
        raise ValueError(f"unit names must be unique, got duplicates {sorted({n for n in names if names.count(n) > 1})}")
    executor, printer = executor or SerialExecutor(), printer or (lambda _: None)
    results: list[UnitResult | None] = [None] * len(units)
    todo = []
    for i, unit in enumerate(units):
        if unit.result_file is not None and unit.result_file.is_file():
            results[i] = UnitResult(unit.name, json.loads(unit.result_file.read_text()), skipped=True)
        else:
            todo.append(i)
    failures: dict[str, str] = {}
    finished = [0]

    def on_done(j: int, outcome: tuple[bool, Any, float, float]) -> None:
        unit = units[todo[j]]
        ok, value, wall, cpu = outcome
        finished[0] += 1
        progress = f"[{finished[0]}/{len(todo)}]"
        if not ok:
            failures[unit.name] = value
            printer(f"{progress} unit {unit.name} FAILED")
            return
        if unit.result_file is not None:
            write_json(unit.result_file, value)
        results[todo[j]] = UnitResult(unit.name, value, skipped=False, wall_seconds=wall, cpu_seconds=cpu)
        printer(f"{progress} unit {unit.name}: {wall:.1f} s wall, {cpu:.1f} s CPU")

    if len(todo) < len(units):
        printer(f"{len(units) - len(todo)} of {len(units)} unit(s) already stored, {len(todo)} to run")
    if todo:
        executor.map([units[i] for i in todo], on_done)
    if failures:
        raise UnitsFailedError(failures, results)
    return [r for r in results if r is not None]

