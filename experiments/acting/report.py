"""The acting-rule screen's report: per stage, every cell's score over runs (one score per run: the mean over its
episodes), paired run by run against today's default cell, the best cell and the behaviour policy."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.acting.cells import DEFAULT_CELL
from experiments.common.records import section, table, write_report
from experiments.common.stats import interval, mean_with_ci, paired_difference

#: the per-run metrics of a cell: (summary key, higher is better)
METRICS = {"reward": True, "collision": False, "jerk_per_step": False}


def load_records(raw: Path) -> dict[str, dict[str, dict[int, dict[str, Any]]]]:
    """The stored records as ``{stage: {cell: {seed: summary}}}`` (the behaviour policy under stage ``"behaviour"``)."""
    out: dict[str, dict[str, dict[int, dict[str, Any]]]] = {}
    for path in sorted(raw.glob("seed*/**/*.json")):
        record = json.loads(path.read_text())
        out.setdefault(record["stage"], {}).setdefault(record["cell"], {})[int(record["seed"])] = record["summary"]
    return out


def _paired(cell: Mapping[int, Mapping[str, float]], base: Mapping[int, Mapping[str, float]], metric: str,
            higher: bool) -> dict[str, float] | None:
    seeds = sorted(set(cell) & set(base))
    if len(seeds) < 2:
        return None
    # paired_difference gives better − worse for a cost: report cell − base in the metric's own units
    diff = paired_difference([cell[s][metric] for s in seeds], [base[s][metric] for s in seeds])
    return {**diff, "higher_is_better": higher}


def stage_summary(cells: Mapping[str, Mapping[int, Mapping[str, float]]],
                  behaviour: Mapping[int, Mapping[str, float]], reps: int) -> dict[str, Any]:
    """Every cell of one stage: its mean over runs with rliable's interval, SD over runs, the other metrics, and
    its paired differences with the default cell, the best cell (by mean reward) and the behaviour policy."""
    scores = {c: np.array([[runs[s]["reward"]] for s in sorted(runs)]) for c, runs in cells.items()}  # (n_runs, 1)
    ci = mean_with_ci(scores, reps=reps)
    most = max(len(runs) for runs in cells.values())  # the best cell: among those with every run
    best = max((c for c in cells if len(cells[c]) == most), key=lambda c: ci[c]["mean"])
    out: dict[str, Any] = {"best": best, "cells": {}}
    for name, runs in cells.items():
        seeds = sorted(runs)
        row: dict[str, Any] = {"seeds": seeds, "reward": ci[name],
                               "reward_sd_over_runs": float(np.std([runs[s]["reward"] for s in seeds], ddof=1))
                               if len(seeds) > 1 else float("nan")}
        for key in ("collision", "jerk_per_step", "mean_executed_length", "ms_per_plan"):
            row[key] = float(np.mean([runs[s][key] for s in seeds]))
        for ref_name, ref in (("default", cells.get(DEFAULT_CELL, {})), ("best", cells[best]),
                              ("behaviour", behaviour)):
            same = ref is runs  # a cell against itself: no comparison
            row[f"vs_{ref_name}"] = {m: None if same else _paired(runs, ref, m, h) for m, h in METRICS.items()}
        out["cells"][name] = row
    return out


def aggregate(records: Mapping[str, Mapping[str, Mapping[int, Mapping[str, float]]]], reps: int = 2000) -> dict[str, Any]:
    """:func:`stage_summary` of every stage, and the behaviour policy's scores."""
    behaviour = dict(records.get("behaviour", {}).get("behaviour", {}))
    order = sorted((s for s in records if s != "behaviour"),
                   key=lambda s: (s != "pretrained", int(s.removeprefix("online_")) if s.startswith("online_") else 0))
    stages = {stage: stage_summary(records[stage], behaviour, reps) for stage in order}
    seeds = sorted(behaviour)
    mean = {key: float(np.mean([behaviour[s][key] for s in seeds])) if seeds else None
            for key in ("reward", "collision", "jerk_per_step")}
    sd = float(np.std([behaviour[s]["reward"] for s in seeds], ddof=1)) if len(seeds) > 1 else float("nan")
    return {"stages": stages, "behaviour": {"seeds": seeds, **mean, "reward_sd_over_runs": sd}}


def _diff(stat: Mapping[str, float] | None, digits: int = 1) -> str:
    if stat is None:
        return "—"
    return f"{interval(stat, digits=digits)} ({stat['x_better_runs']}/{stat['runs']})"


def _stage_table(stage: Mapping[str, Any], order: Sequence[str]) -> list[str]:
    rows = []
    for name in [c for c in order if c in stage["cells"]] + sorted(set(stage["cells"]) - set(order)):
        r = stage["cells"][name]
        mark = " **(best)**" if name == stage["best"] else " (default)" if name == DEFAULT_CELL else ""
        rows.append([f"`{name}`{mark}", interval(r["reward"], "mean", 1, ""), f"{r['reward_sd_over_runs']:.1f}",
                     _diff(r["vs_default"]["reward"]), _diff(r["vs_best"]["reward"]), _diff(r["vs_behaviour"]["reward"]),
                     f"{r['collision']:.3f}", f"{r['jerk_per_step']:.3f}", f"{r['mean_executed_length']:.2f}",
                     f"{r['ms_per_plan']:.2f}"])
    return table(["cell (selection@execution)", "reward [95 % CI]", "SD over runs", "− default [CI] (runs ahead)",
                  "− best [CI]", "− behaviour [CI]", "collisions", "jerk / step", "mean L_t", "ms / plan"], rows)


def markdown(summary: Mapping[str, Any], order: Sequence[str]) -> str:
    """The report's Markdown."""
    b = summary["behaviour"]
    lines = [
        "# Acting rules on frozen checkpoints", "",
        f"Command: `{summary['command']}` ({summary['date']}).", "",
        f"Checkpoints: {summary['checkpoints']}. Scenarios: {summary['scenarios']}; {summary['episodes']} episodes "
        "per run and cell, the same scenarios for every cell of a run (paired). One score per run (the mean over its "
        "episodes); intervals over runs: the mean's from rliable's bootstrap, the paired differences' Student-t "
        "(scipy). `runs ahead`: runs where the cell beats the reference. A cell is `selection@execution`: "
        "selections `elite` (the elite mean of 8 by min_j Q_j), `best` (n_elite = 1), `uncertainty` "
        "(softmax(mean_j Q_j / τ), τ the twin critics' mean disagreement), `mean` (all candidates, no critic: the "
        "control of `uncertainty`), `sample` (one candidate), `zero_noise` (the flow from x_0 = 0); executions "
        "`eq7` (Eq. 7, δ = 0), `replan` (one action, then a new chunk), `whole` (the whole chunk), `ensemble` "
        "(ACT's temporal ensembling, m = 0.01). `ms / plan`: wall time of `predict` per plan made, on a machine "
        "shared with the other worker.",
    ]
    if b["reward"] is not None:
        lines += ["", f"Behaviour policy on the same scenarios ({len(b['seeds'])} runs): reward {b['reward']:.1f} "
                  f"(SD over runs {b['reward_sd_over_runs']:.1f}), collisions {b['collision']:.3f}, jerk / step "
                  f"{b['jerk_per_step']:.3f}."]
    for stage, s in summary["stages"].items():
        lines += section(f"{stage} ({len(s['cells'][s['best']]['seeds'])} runs)", *_stage_table(s, order))
    return "\n".join(lines) + "\n"


def write(summary: Mapping[str, Any], out: Path, order: Sequence[str]) -> list[Path]:
    """``acting.json`` and ``acting.md`` in ``out``."""
    return write_report(out, "acting", summary, markdown(summary, order))
