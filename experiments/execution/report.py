"""The report of the execution-rule study: each rule against fixed chunks and its controls, paired per seed."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from experiments.common.records import section, table
from experiments.common.stats import interval, paired_difference
from sb3_ua2c.execution import format_length_shares

MODES = ("deterministic", "sampled")


def run_score(entry: Mapping[str, Any], metric: str) -> float:
    """The mean of ``metric`` over one run's evaluation episodes of one arm and mode."""
    return float(np.mean([float(e[metric]) for e in entry["episodes"]]))


def summarize(records: Sequence[Mapping[str, Any]], metric: str = "reward") -> dict[str, Any]:
    """``{checkpoint: {mode: {arm: {...}}}}``: scores, ``L_t`` shares, and each rule paired with fixed and its controls."""
    records = sorted(records, key=lambda r: r["seed"])
    out: dict[str, Any] = {}
    for checkpoint in records[0]["checkpoints"]:
        arms = list(records[0]["checkpoints"][checkpoint])
        if not all(list(r["checkpoints"][checkpoint]) == arms for r in records):
            raise ValueError(f"the runs evaluated {checkpoint} under different arms; rerun them alike")
        for mode in MODES:
            rows: dict[str, Any] = {}
            for arm in arms:
                entries = [r["checkpoints"][checkpoint][arm][mode] for r in records]
                scores = [run_score(e, metric) for e in entries]
                collision = "collision" in entries[0]["episodes"][0]  # MixedTraffic-v0's; OGBench has none
                rows[arm] = {"per_seed": scores, "mean": float(np.mean(scores)),
                              "collision": float(np.mean([run_score(e, "collision") for e in entries])) if collision
                              else None,
                              "length_shares": np.mean([e["length_shares"] for e in entries], axis=0).tolist()}
            for arm in arms:
                if ":" in arm or arm == "fixed":
                    continue
                against = ["fixed", *sorted(a for a in arms if a.startswith(f"{arm}:"))]  # fixed, then the controls
                rows[arm]["paired"] = {other: paired_difference(rows[arm]["per_seed"], rows[other]["per_seed"])
                                       if len(records) > 1 else None for other in against}
            out.setdefault(checkpoint, {})[mode] = rows
    return out


def online_protocol(records: Sequence[Mapping[str, Any]], metric: str = "reward") -> dict[str, dict[str, Any]]:
    """Figure 2 (c)'s comparison: fine-tuned and acting with each rule, against fixed chunks, paired per seed."""
    records = sorted(records, key=lambda r: r["seed"])
    checkpoints = records[0]["checkpoints"]
    if "online_fixed" not in checkpoints:
        return {}
    out: dict[str, dict[str, Any]] = {}
    for name in checkpoints:
        rule = name.removeprefix("online_")
        if not name.startswith("online_") or rule == "fixed":
            continue
        for mode in MODES:
            ours = [run_score(r["checkpoints"][name][rule][mode], metric) for r in records]
            base = [run_score(r["checkpoints"]["online_fixed"]["fixed"][mode], metric) for r in records]
            out.setdefault(rule, {})[mode] = {
                "per_seed": ours, "fixed_per_seed": base, "mean": float(np.mean(ours)), "fixed_mean": float(np.mean(base)),
                "paired": paired_difference(ours, base) if len(records) > 1 else None,
            }
    return out


def _interval(p: Mapping[str, float] | None, digits: int = 1) -> str:
    return "n/a" if p is None else interval(p, digits=digits)


def overview(summary: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """Per rule, the means over every checkpoint and mode of its score minus fixed chunks' and its controls'."""
    cells: dict[str, dict[str, list[float]]] = {}
    for modes in summary.values():
        for arms in modes.values():
            for arm, row in arms.items():
                if ":" in arm or arm == "fixed":
                    continue
                cell = cells.setdefault(arm, {"fixed": [], "random": [], "fixed_k": [], "mean_length": []})
                for key, other in (("fixed", "fixed"), ("random", f"{arm}:random"), ("fixed_k", f"{arm}:fixed_k")):
                    cell[key].append(row["mean"] - arms[other]["mean"])
                cell["mean_length"].append(float(np.dot(np.arange(1, len(row["length_shares"]) + 1),
                                                        row["length_shares"])))
    return {arm: {key: float(np.mean(values)) for key, values in cell.items()} | {"cells": len(cell["fixed"])}
            for arm, cell in cells.items()}


def threshold_quantiles(records: Sequence[Mapping[str, Any]]) -> dict[str, list[float]]:
    """The calibrated ``delta_u`` (``(k,)`` nats) of each quantile rule on the pre-trained checkpoints, over runs."""
    out = {}
    for arm, modes in records[0]["checkpoints"]["offline"].items():
        if modes["deterministic"].get("thresholds") is not None:
            rows = [r["checkpoints"]["offline"][arm]["deterministic"]["thresholds"] for r in records]
            out[arm] = np.mean(rows, axis=0).tolist()
    return out


def _overview_lines(summary: Mapping[str, Any], digits: int) -> list[str]:
    return table(["rule", "− fixed", "− random cut", "− fixed k'", "mean L_t", "cells"],
                 ([arm, *(f"{row[k]:+.{digits}f}" for k in ("fixed", "random", "fixed_k")), f"{row['mean_length']:.2f}",
                   row["cells"]] for arm, row in overview(summary).items()))


def _online_lines(online: Mapping[str, Any], metric: str, digits: int) -> list[str]:
    return table(["rule", "mode", metric, "fixed chunks", "paired per seed"],
                 ([rule, mode, f"{row['mean']:.{digits}f}", f"{row['fixed_mean']:.{digits}f}",
                   _interval(row["paired"], digits)] for rule, modes in online.items() for mode, row in modes.items()))


def secondary_lines(metric: str, meaning: str, summary: Mapping[str, Any], online: Mapping[str, Any],
                    digits: int = 1) -> list[str]:
    """A second score of the same runs: its :func:`overview` and :func:`online_protocol` under one heading."""
    lines = [f"## Second score: {metric} ({meaning})", "",
             "The rules were chosen on the first score; this one is reported, not used for a choice.", "",
             *_overview_lines(summary, digits)]
    if online:
        lines += ["", *_online_lines(online, metric, digits)]
    return [*lines, ""]


def _arm_row(arm: str, row: Mapping[str, Any], digits: int) -> list[str]:
    """One arm of a checkpoint's table: its score, collision rate, ``L_t`` and paired differences."""
    paired = row.get("paired") or {}
    random_cut = next((v for k, v in paired.items() if k.endswith(":random")), None)
    k_cut = next((v for k, v in paired.items() if k.endswith(":fixed_k")), None)
    return [arm, f"{row['mean']:.{digits}f}", "—" if row["collision"] is None else f"{row['collision']:.2f}",
            format_length_shares(row["length_shares"]), _interval(paired["fixed"], digits) if "fixed" in paired else "",
            _interval(random_cut, digits) if paired else "", _interval(k_cut, digits) if paired else ""]


def markdown(summary: Mapping[str, Any], header: Sequence[str], thresholds: Mapping[str, Sequence[float]] = {},
             online: Mapping[str, Any] = {}, task: str = "MixedTraffic-v0", metric: str = "reward",
             digits: int = 1, secondary: Sequence[str] = ()) -> str:
    """The report: the overview, online protocol, ``H_u`` quantiles, ``secondary`` lines and every checkpoint's tables."""
    lines = [f"# Execution rules on {task}", "", *header,
             *section("Overview", "Means over every checkpoint and mode below (descriptive; the intervals are in the "
                      "tables).", "", *_overview_lines(summary, digits))]
    if online:
        lines += section("Online protocol (Figure 2 (c)): fine-tuned and acting with the rule, against fixed chunks",
                         *_online_lines(online, metric, digits))
    if thresholds:
        lines += section("H_u over dataset histories (pre-trained checkpoints, mean over runs)",
                         *table(["quantile rule", "δ_u for u = 1..k (nats)"],
                                ([arm, " ".join(f"{x:+.2f}" for x in values)] for arm, values in thresholds.items())))
    lines += ["", *secondary]
    for checkpoint, modes in summary.items():
        for mode, arms in modes.items():
            lines += [f"## {checkpoint}, {mode}", "", *table(
                ["arm", f"{metric} (mean of runs)", "collision", "L_t = 1..k (% of plans)", "− fixed", "− random cut",
                 "− fixed k'"], (_arm_row(arm, row, digits) for arm, row in arms.items())), ""]
    return "\n".join(lines)
