"""What the acting-rule screen evaluates: cells (a selection × an execution) applied to a frozen checkpoint, the
checkpoints of a head-to-head run by stage, and one unit per (seed, stage, cell)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from envs.evaluation import evaluate, evaluate_behaviour, summarize
from experiments.peers.common import dataset_behaviour
from sb3_ua2c.config import ExecutionRule
from sb3_ua2c.offline import load_dataset
from sb3_ua2c.pipeline import env_settings
from sb3_ua2c.policies import DEFAULT_N_ELITE

#: selections by cell name: the policy's ``selection`` and, for the elite, ``n_elite``
SELECTIONS: dict[str, dict[str, Any]] = {
    "elite": {"selection": "elite", "n_elite": DEFAULT_N_ELITE},  # same as default: the cell named after it
    "best": {"selection": "elite", "n_elite": 1},  # same as default: the paper's best candidate, n_elite = 1
    "uncertainty": {"selection": "uncertainty"},
    "mean": {"selection": "mean"},  # the control of "uncertainty": the same average without the critics
    "sample": {"selection": "sample"},
    "zero_noise": {"selection": "zero_noise"},
}
#: executions by cell name (:class:`~sb3_ua2c.config.ExecutionRule`)
EXECUTIONS: dict[str, ExecutionRule] = {
    "eq7": ExecutionRule(),  # Eq. 7 with δ = 0, today's default
    "replan": ExecutionRule("replan"),
    "whole": ExecutionRule(entropy_threshold=math.inf),
    "ensemble": ExecutionRule("ensemble"),
}
#: the cell that acts as ``predict`` does today: every other cell is paired against it
DEFAULT_CELL = "elite@eq7"
#: the screened cells, the default first: every selection with Eq. 7, then every execution with the
#: uncertainty-aware selection, the elite and the mean (the uncertainty-aware selection's control)
CELLS: tuple[str, ...] = (
    DEFAULT_CELL, "uncertainty@eq7", "mean@eq7", "best@eq7", "sample@eq7", "zero_noise@eq7",
    *(f"{s}@{e}" for s in ("uncertainty", "elite", "mean") for e in ("ensemble", "whole", "replan")),
)
#: checkpoints by stage: Phase 1, and the UA2C arm's snapshots after online steps (``peers --snapshot-every``)
STAGES = ("pretrained", "online_5000", "online_20000")


def parse_cell(cell: str) -> tuple[dict[str, Any], ExecutionRule]:
    """``"<selection>@<execution>"`` -> (the selection's settings, the execution rule); a ``ValueError`` names a bad one."""
    selection, _, execution = cell.partition("@")
    if selection not in SELECTIONS or execution not in EXECUTIONS:
        raise ValueError(f"--cells: {cell!r} is not <selection>@<execution> with a selection of {list(SELECTIONS)} "
                         f"and an execution of {list(EXECUTIONS)}")
    return SELECTIONS[selection], EXECUTIONS[execution]


def stage_checkpoint(seed_work: Path, stage: str, arm: str = "ua2c") -> Path:
    """The checkpoint of ``stage`` in a head-to-head seed's work directory (``FileNotFoundError`` says what is missing)."""
    if stage == "pretrained":
        found = sorted(seed_work.glob("pretrain_k*.zip"))
        if len(found) != 1:
            raise FileNotFoundError(f"{seed_work}: expected one Phase-1 checkpoint pretrain_k*.zip, found {found}")
        return found[0]
    if not stage.startswith("online_") or not stage.removeprefix("online_").isdigit():
        raise ValueError(f"--stages: {stage!r} is not 'pretrained' or 'online_<steps>'")
    path = seed_work / arm / "snapshots" / f"model_{stage.removeprefix('online_')}_steps.zip"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: run `python -m experiments peers ... --snapshot-every N` "
                                f"with a multiple of N online steps first")
    return path


#: per episode, what a record keeps (columns of equal length)
EPISODE_COLUMNS = ("reward", "collision", "jerk_per_step", "length", "mean_executed_length", "ms_per_plan")


def episode_columns(episodes: list[Any]) -> dict[str, list[float]]:
    """The :data:`EPISODE_COLUMNS` of evaluation episodes, rounded to 4 decimals (a compact record)."""
    return {key: [round(float(getattr(e, key)), 4) for e in episodes] for key in EPISODE_COLUMNS}


def run_cell(seed: int, stage: str, cell: str, checkpoint: str, dataset: str, scenario_seed: int,
             episodes: int) -> dict[str, Any]:
    """One unit: ``checkpoint`` acting by ``cell`` on ``episodes`` scenarios of ``scenario_seed``."""
    th.set_num_threads(1)
    settings, execution = parse_cell(cell)
    results = evaluate(checkpoint, n_episodes=episodes, seeds=(scenario_seed,),
                       env_settings_=env_settings(load_dataset(dataset)), execution=execution, **settings)
    summary = summarize(results)
    summary["ms_per_plan"] = float(np.sum([e.acting_seconds for e in results]) * 1000.0
                                   / max(1, sum(len(e.plan_lengths) for e in results)))
    return {"seed": seed, "stage": stage, "cell": cell, "checkpoint": checkpoint, "scenario_seed": scenario_seed,
            "summary": summary, "episodes": episode_columns(results)}


def run_behaviour(seed: int, dataset: str, scenario_seed: int, episodes: int) -> dict[str, Any]:
    """One unit: the dataset's behaviour policy on the scenarios every cell of ``seed`` acts on."""
    ds = load_dataset(dataset)
    results = evaluate_behaviour(dataset_behaviour(ds), episodes, (scenario_seed,), env_settings(ds))
    summary = summarize(results)
    summary["ms_per_plan"] = math.nan
    return {"seed": seed, "stage": "behaviour", "cell": "behaviour", "scenario_seed": scenario_seed,
            "summary": summary, "episodes": episode_columns(results)}
