"""The OGBench benchmark as executor units: the task's dataset (``<work>/data/``) first, then one unit per (arm,
seed), its record in ``<work>/units/<task>/<arm>-s<seed>/record.json``."""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from experiments.common.cli import select_seeds
from experiments.common.estimate import estimate as scaled
from experiments.common.estimate import recorded, seconds_per_size, wall_seconds
from experiments.common.records import check_budget_record
from experiments.common.runner import Executor, Unit, run_units
from experiments.ogbench.data import TaskName
from experiments.ogbench.unit import ARMS, OGBenchBudget, dataset_file, ensure_dataset, run_ogbench_unit

#: The default task: see docs/ogbench.md ("Why these tasks") and the probes in docs/research-log.md.
DEFAULT_TASK = "pointmaze-medium-navigate-singletask-task1-v0"

#: The budget of each task family (3 arms x 5 seeds in 3 h wall on 2 cores); ``QUICK_BUDGET`` runs end to end
#: in well under a minute (CI).
BUDGETS = {"cube-single": OGBenchBudget(), "pointmaze-medium": OGBenchBudget(),
           "scene": OGBenchBudget(dataset_episodes=100, sparse=True)}
QUICK_BUDGET = OGBenchBudget(dataset_episodes=2, episode_steps=30, pretrain_steps=4, finetune_steps=25,
                             eval_episodes=2, curve_points=1, curve_episodes=1, max_episode_steps=20)

_TASK_ID = re.compile(r"^task[1-5]$")


def check_task(task: str) -> TaskName:
    """``task`` parsed, or a ``ValueError`` naming ``--task`` unless it is a single task whose data can be made here."""
    try:
        name = TaskName.parse(task)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--task: {exc}") from None
    parts = task.split("-")
    if not _TASK_ID.match(parts[-2]):
        raise ValueError(f"--task: {task!r} names no evaluation task; append one of task1..task5, "
                         f"e.g. {task.rsplit('-', 1)[0]}-task2-{parts[-1]}")
    return name


def check_arms(arms: Sequence[str]) -> list[str]:
    """``arms`` as a list without repeats, or a ``ValueError`` naming ``--arms``."""
    unknown = [a for a in arms if a not in ARMS]
    if unknown or not arms:
        raise ValueError(f"--arms: unknown arm(s) {unknown} (choose from {sorted(ARMS)})" if unknown
                         else "--arms: give at least one arm")
    return list(dict.fromkeys(arms))


def default_budget(task: str, quick: bool = False) -> OGBenchBudget:
    """The budget of ``task``: :data:`QUICK_BUDGET` with ``quick``, else its family's in :data:`BUDGETS`."""
    family = check_task(task).env_name.rsplit("-", 1)[0]  # cube-single-v0 -> cube-single
    if family not in BUDGETS:
        raise ValueError(f"--task: no budget is set for {family!r} tasks (known: {sorted(BUDGETS)})")
    return QUICK_BUDGET if quick else BUDGETS[family]


def estimate(arms: Sequence[str], n_seeds: int, budget: OGBenchBudget, workers: int,
             reports: Sequence[dict[str, Any]] | None = None) -> dict[str, float]:
    """CPU and wall seconds of a run from the unit seconds in the ``reports`` (default: the committed ones)."""
    reports = recorded("**/ogbench.json") if reports is None else reports
    rates = seconds_per_size((r["arm"], r["seconds"]["total_cpu"], rep["budget"]["pretrain_steps"]
                              + rep["budget"]["finetune_steps"]) for rep in reports for r in rep.get("records", []))
    per_unit = scaled(rates, {arm: budget.pretrain_steps + budget.finetune_steps for arm in arms})
    units = [per_unit[arm] for arm in arms for _ in range(n_seeds)]
    return {"units_cpu": sum(units), "total_cpu": sum(units), "wall": wall_seconds(units, workers)}


def format_estimate(task: str, arms: Sequence[str], seeds: Sequence[int], budget: OGBenchBudget, workers: int,
                    est: dict[str, float]) -> str:
    return (f"OGBench {task}: arms {list(arms)} x seeds {list(seeds)} = {len(arms) * len(seeds)} unit(s), "
            f"{budget.dataset_episodes} dataset episodes, {budget.pretrain_steps} offline updates, "
            f"{budget.finetune_steps} online steps, {budget.eval_episodes} evaluation episodes; estimated "
            f"{est['total_cpu'] / 3600:.2f} CPU-h, {est['wall'] / 3600:.2f} h wall with {workers} worker(s) "
            "(from the committed records' unit times)")


def generation_unit(task: str, budget: OGBenchBudget, data_dir: str) -> dict[str, Any]:
    """Stage 1: the dataset of ``task`` (generated when missing); its path and measurements."""
    path, generation = ensure_dataset(task, budget, data_dir)
    return {"task": task, "path": str(path), "generation": generation, "budget": budget.to_dict()}


def unit_dir(work: Path, task: str, arm: str, seed: int) -> Path:
    return Path(work) / "units" / task / f"{arm}-s{seed}"


def build_units(task: str, arms: Sequence[str], seeds: Sequence[int], budget: OGBenchBudget,
                work: str | Path) -> tuple[Unit, list[Unit]]:
    """The dataset unit and the (arm, seed) units of a run, with their result files under ``work``."""
    work = Path(work)
    data_dir = work / "data"
    data = Unit(f"data/{task}", generation_unit, {"task": task, "budget": budget, "data_dir": str(data_dir)},
                result_file=dataset_file(task, budget, data_dir).with_suffix(".json"))
    units = [Unit(f"{task}/{arm}-s{seed}", run_ogbench_unit,
                  {"arm": arm, "task": task, "seed": seed, "budget": budget,
                   "out_dir": str(unit_dir(work, task, arm, seed)), "data_dir": str(data_dir)},
                  result_file=unit_dir(work, task, arm, seed) / "record.json") for arm in arms for seed in seeds]
    return data, units


def check_stored_budget(units: Sequence[Unit], budget: OGBenchBudget) -> None:
    """Refuse a work directory whose stored units ran under another budget (``--work``)."""
    for unit in units:  # each with its result file (build_units)
        check_budget_record(unit.result_file, budget.to_dict(), f"--work: {unit.result_file}",
                            read=lambda record: record.get("budget") or {}, write=False)


def run_benchmark(task: str, arms: Sequence[str], seeds: Sequence[int], budget: OGBenchBudget, work: str | Path,
                  executor: Executor, printer: Any = print) -> list[dict[str, Any]]:
    """Stage 1 then stage 2 through ``executor``; returns the records of every (arm, seed) unit."""
    data, units = build_units(task, arms, seeds, budget, work)
    check_stored_budget([data, *units], budget)
    run_units([data], executor, printer=printer)
    return [r.value for r in run_units(units, executor, printer=printer)]


def stored_records(task: str, arms: Sequence[str], seeds: Sequence[int], work: str | Path) -> list[dict[str, Any]]:
    """The records already stored in ``work`` (``--report-only``); a missing one is a ``ValueError``."""
    paths = {f"{arm}-s{seed}": unit_dir(Path(work), task, arm, seed) / "record.json" for arm in arms for seed in seeds}
    missing = [name for name, path in paths.items() if not path.is_file()]
    if missing:
        raise ValueError(f"--report-only: no stored record for {missing} under {Path(work) / 'units' / task}")
    return [json.loads(path.read_text()) for path in paths.values()]


def seeds_arg(values: Iterable[int]) -> list[int]:
    """The distinct seeds of ``--seeds`` in increasing order, each in ``[0, 1000)`` (below the next reset base)."""
    return sorted(select_seeds(list(values), [], high=1000))

