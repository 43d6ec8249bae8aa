"""Report of the OGBench benchmark: ``ogbench.md``, ``ogbench.json`` and the learning-curve PNGs."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common import records as records_module
from experiments.common.records import figure, table
from experiments.common.stats import interval, iqm_with_ci, paired_difference, probability_of_improvement
from sb3_ua2c.execution import format_length_shares

PHASES = ("offline", "online")
LABELS = {"adaptive": "UA2C (adaptive chunks)", "fixed": "fixed chunks (k = 5, δ = inf)", "onestep": "one-step (k = 1)"}
#: Q-chunking's protocol and published result (Li, Zhou, Levine 2025, OGBench single-task, 5 domains).
QC_REFERENCE = {
    "offline_updates": 1_000_000, "online_steps": 1_000_000, "dataset_transitions": 1_000_000,
    "mean_success": {"QC": 0.86, "FQL (one-step)": 0.58}, "ranking": "fixed chunks (QC) > one-step (FQL)",
}
SUCCESS_BAR = 0.10


def success_matrix(records: Sequence[Mapping[str, Any]], phase: str) -> np.ndarray:
    """``(n_runs, 1)``: each run's success rate after ``phase``, rows by seed."""
    if phase not in PHASES:
        raise ValueError(f"phase must be one of {PHASES}, got {phase!r}")
    if not records:
        raise ValueError("records must not be empty")
    rates = [float(r[f"success_{phase}"]) for r in sorted(records, key=lambda r: r["seed"])]
    return np.asarray(rates, dtype=np.float64)[:, None]  # (n_runs,) -> (n_runs, 1)


def records_from_report(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The run records a written ``ogbench.json`` keeps, to rebuild the report where the unit records are gone."""
    return [{**r, "task": summary["task"], "budget": summary["budget"],
             **{f"eval_{phase}": {"length_shares": v} for phase, v in r.get("length_shares", {}).items()}}
            for r in summary["records"]]


def by_arm(records: Sequence[Mapping[str, Any]]) -> dict[str, list[Mapping[str, Any]]]:
    """Records grouped by arm, arms in their first-seen order."""
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for record in records:
        groups.setdefault(record["arm"], []).append(record)
    return groups


def ranking(poi: Mapping[str, float] | None) -> str:
    """Our ranking of fixed chunks vs one-step from ``P(fixed > one-step)`` and its 95 % interval."""
    if poi is None:
        return "not measured (needs both the fixed and the one-step arm)"
    if poi["ci_low"] > 0.5:
        return "fixed chunks > one-step"
    if poi["ci_high"] < 0.5:
        return "one-step > fixed chunks"
    return "no clear ranking (the interval of P(fixed > one-step) contains 0.5)"


def summarize(records: Sequence[Mapping[str, Any]], reps: int = 2000) -> dict[str, Any]:
    """Everything the report shows: per arm and phase the success rates, per pair of arms their comparisons."""
    groups = by_arm(records)
    tasks = sorted({r["task"] for r in records})
    if len(tasks) != 1:
        raise ValueError(f"records must come from one task, got {tasks}")
    arms: dict[str, Any] = {}
    matrices = {phase: {arm: success_matrix(recs, phase) for arm, recs in groups.items()} for phase in PHASES}
    for phase in PHASES:
        intervals = iqm_with_ci(matrices[phase], reps=reps)
        for arm, matrix in matrices[phase].items():
            arms.setdefault(arm, {"seeds": sorted(r["seed"] for r in groups[arm])})[phase] = {
                "mean": float(matrix.mean()), "per_seed": matrix[:, 0].tolist(), **intervals[arm]}
            evaluations = [r.get(f"eval_{phase}") or {} for r in groups[arm]]
            if all("length_shares" in e for e in evaluations):  # recorded since 2026-12-04
                arms[arm][phase]["length_shares"] = np.mean([e["length_shares"] for e in evaluations], axis=0).tolist()
    pairs: dict[str, Any] = {}
    for x, y in itertools.combinations(groups, 2):
        pairs[f"{x} > {y}"] = {phase: probability_of_improvement(matrices[phase][x], matrices[phase][y], reps=reps)
                               for phase in PHASES}
        if arms[x]["seeds"] == arms[y]["seeds"] and len(arms[x]["seeds"]) >= 2:
            for phase in PHASES:
                pairs[f"{x} > {y}"][f"{phase}_paired"] = paired_difference(matrices[phase][x][:, 0], matrices[phase][y][:, 0])
    poi = pairs.get("fixed > onestep", {}).get("online")
    if poi is None and "onestep > fixed" in pairs:
        flipped = pairs["onestep > fixed"]["online"]
        poi = {"probability": 1 - flipped["probability"], "ci_low": 1 - flipped["ci_high"],
               "ci_high": 1 - flipped["ci_low"]}
    best = max((a[p]["mean"] for a in arms.values() for p in PHASES), default=0.0)
    ours = ranking(poi)
    return {
        "task": tasks[0], "budget": records[0]["budget"], "arms": arms, "improvement": pairs,
        "ranking": {"ours_online": ours, "qc": QC_REFERENCE["ranking"], "agrees_with_qc": ours == "fixed chunks > one-step"},
        "above_bar": best > SUCCESS_BAR, "best_mean_success": best, "qc_reference": QC_REFERENCE,
        "seconds": {arm: sum(r["seconds"]["total_cpu"] for r in recs) for arm, recs in groups.items()},
        "n_units": len(records),
    }


def _pct(x: float) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:.1f} %"


def _iqm(stat: Mapping[str, float], key: str = "iqm") -> str:
    return f"{_pct(stat[key])} [{_pct(stat['ci_low'])}, {_pct(stat['ci_high'])}]"


def format_markdown(summary: Mapping[str, Any], command: str | None = None) -> str:
    """``ogbench.md``: the success table, probabilities of improvement, budget next to QC's, ranking."""
    b, qc = summary["budget"], summary["qc_reference"]
    lines = [f"# OGBench: {summary['task']}", ""]
    if command:
        lines += [f"Command: `{command}`" + (f" ({summary['date']})" if summary.get("date") else ""), ""]
    cpu = sum(summary["seconds"].values()) / 60
    est = summary.get("estimate") or {}
    compute = f"Compute: {cpu:.0f} CPU-min over {summary['n_units']} units"
    if est.get("total_cpu"):  # the cost model's estimate bounds the run unless its units cost more than modelled
        bound = "an upper bound" if cpu <= est["total_cpu"] / 60 else "exceeded: the units cost more than the cost model"
        compute += f" (estimate {est['total_cpu'] / 60:.0f} CPU-min, {bound})"
    lines += [compute + ".", ""]
    lines += ["Success rate after each phase. A run's score is its success rate over its evaluation episodes; "
              "the table gives the mean over runs, the IQM over runs with its stratified bootstrap 95 % interval "
              "(rliable), and every run's rate.", ""]
    lines += table(["arm", "seeds", "offline mean", "offline IQM [95 % CI]", "online mean", "online IQM [95 % CI]",
                    "per seed (online)"],
                   ([LABELS.get(arm, arm), len(s["seeds"]), _pct(s["offline"]["mean"]), _iqm(s["offline"]),
                     _pct(s["online"]["mean"]), _iqm(s["online"]), ", ".join(f"{100 * v:.0f}" for v in s["online"]["per_seed"])]
                    for arm, s in summary["arms"].items()))
    shares = [(arm, s) for arm, s in summary["arms"].items() if "length_shares" in s["offline"]]
    if shares:
        lines += ["", "Executed lengths L_t of the evaluation plans (share of plans with L_t = 1..k, %, mean over runs):",
                  "", *table(["arm", "offline", "online"],
                             ([LABELS.get(arm, arm), format_length_shares(s["offline"]["length_shares"]),
                               format_length_shares(s["online"].get("length_shares", []))] for arm, s in shares))]
    if not summary["improvement"]:
        lines += ["", "One arm ran: no pair of arms to compare within this run (`python -m experiments paired` "
                  "pairs its per-seed rates with another run's on the same seeds)."]
    else:
        lines += ["", "Probability of improvement P(X > Y) over runs (0.5 = no difference), and the mean paired "
                  "per-seed difference of the success rate X − Y (percentage points) with its 95 % Student-t "
                  "interval:", "", *table(
                      ["X > Y", "P offline [95 % CI]", "P online [95 % CI]", "X − Y offline", "X − Y online"],
                      ([pair, *(interval(p[ph], "probability", sign="") for ph in PHASES),
                        *(_iqm(p[f"{ph}_paired"], "difference") if f"{ph}_paired" in p else "–" for ph in PHASES)]
                       for pair, p in summary["improvement"].items()))]
    r = summary["ranking"]
    lines += ["", "## Budget and ranking next to Q-chunking", "",
              "| | this run | Q-chunking |", "|---|---|---|",
              f"| dataset | {b['dataset_episodes']} episodes x {b['episode_steps'] - 1} transitions, generated here "
              f"| {qc['dataset_transitions']:,} transitions (OGBench's) |",
              f"| offline updates | {b['pretrain_steps']:,} | {qc['offline_updates']:,} |",
              f"| online steps | {b['finetune_steps']:,} | {qc['online_steps']:,} |",
              f"| evaluation | {b['eval_episodes']} episodes per seed | |",
              f"| ranking, fixed chunks vs one-step | {r['ours_online']} | {r['qc']} |", "",
              f"Our ranking {'agrees' if r['agrees_with_qc'] else 'does not agree'} with Q-chunking's. Q-chunking "
              f"reports a mean success of {qc['mean_success']['QC']:.2f} for QC against "
              f"{qc['mean_success']['FQL (one-step)']:.2f} for one-step FQL over five domains.", ""]
    if not summary["above_bar"]:
        lines += [f"**No arm exceeds {100 * SUCCESS_BAR:.0f} % success at this budget** (best mean "
                  f"{_pct(summary['best_mean_success'])}): the ranking above says little.", ""]
    lines += ["Learning curves: `ogbench_online_success.png`, `ogbench_online_return.png`.", ""]
    return "\n".join(lines)


def curve_points(records: Sequence[Mapping[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Evaluation success vs online steps of one arm: steps ``(P,)`` and the mean over seeds ``(P,)``."""
    steps = np.asarray([p["step"] for p in records[0]["curve"]], dtype=np.float64)
    values = np.asarray([[p["success"] for p in r["curve"]] for r in records], dtype=np.float64)  # (seeds, P)
    return steps, values.mean(axis=0)


def return_curve(records: Sequence[Mapping[str, Any]], bins: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Mean return of the online training episodes per bin of environment steps (NaN where none ended)."""
    total = records[0]["budget"]["finetune_steps"]
    edges = np.linspace(0, total, bins + 1)
    episodes = [e for r in records for e in r["training_episodes"]]
    steps = np.asarray([e["step"] for e in episodes], dtype=np.float64)
    returns = np.asarray([e["return"] for e in episodes], dtype=np.float64)
    which = np.clip(np.digitize(steps, edges[1:-1]), 0, bins - 1)
    means = np.array([returns[which == i].mean() if np.any(which == i) else np.nan for i in range(bins)])
    return (edges[:-1] + edges[1:]) / 2, means


def write_plots(records: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """The two learning-curve PNGs: evaluation success and online episode return against online env steps."""
    paths = []
    for name, ylabel, curve in (("ogbench_online_success.png", "evaluation success", curve_points),
                                ("ogbench_online_return.png", "online episode return", return_curve)):
        with figure(out / name, (5.0, 3.6)) as fig:
            ax = fig.add_subplot()
            for arm, recs in by_arm(records).items():
                x, y = curve(recs)
                ax.plot(x, y, marker="o", label=LABELS.get(arm, arm))
            ax.set_xlabel("online environment steps")
            ax.set_ylabel(ylabel)
            ax.set_title(f"{records[0]['task']} ({len(records)} units)", fontsize=9)
            ax.legend(fontsize=8)
        paths.append(out / name)
    return paths


def _length_shares(record: Mapping[str, Any]) -> dict[str, Any]:
    """``{"length_shares": {phase: shares}}`` of a run that recorded them (else ``{}``), kept in ``ogbench.json``
    so that a rebuild from that file alone keeps the L_t table (:func:`records_from_report`)."""
    shares = {p: record[f"eval_{p}"]["length_shares"] for p in PHASES
              if "length_shares" in (record.get(f"eval_{p}") or {})}
    return {"length_shares": shares} if shares else {}


def write_report(records: Sequence[Mapping[str, Any]], out: str | Path, command: str | None = None,
                 estimate: Mapping[str, float] | None = None, reps: int = 2000, date: str | None = None,
                 plots: bool = True) -> dict[str, Any]:
    """Write ``ogbench.md``, ``ogbench.json`` and (``plots``) the PNGs into ``out``; return the summary."""
    summary = summarize(records, reps=reps)
    summary.update(command=command, estimate=dict(estimate) if estimate else None, date=date)
    kept = [{**{k: r[k] for k in ("arm", "seed", "success_offline", "success_online", "curve", "seconds")},
             **_length_shares(r)} for r in records]
    records_module.write_report(Path(out), "ogbench", {**summary, "records": kept}, format_markdown(summary, command),
                              (lambda d: write_plots(records, d)) if plots else None)
    return summary

