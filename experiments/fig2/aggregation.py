"""Aggregation of the per-seed raw results into what ``fig2.json`` holds (:func:`aggregate`)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from experiments.common import names
from experiments.common.budget import library_default
from experiments.common.stats import compare, t_summary
from experiments.fig2.budget import Fig2Budget, RunPaths

#: Comparisons of a method with a baseline in a metric: (a), (b), (b'') jerk per step, (c''') the execution rule
#: alone and, beyond the paper, (a') and (b'): the offline chunk policy with Eq. 7 execution
METHOD_PAIRS = {
    "offline_reward": ("chunk", "onestep", "reward"),
    "offline_jerk": ("chunk", "onestep", "cumulative_jerk"),
    "offline_jerk_per_step": ("chunk", "onestep", "jerk_per_step"),
    "online_execution_rule": ("fixed_adaptive", "fixed", "reward"),
    "offline_reward_chunk_adaptive": ("chunk_adaptive", "onestep", "reward"),
    "offline_jerk_chunk_adaptive": ("chunk_adaptive", "onestep", "cumulative_jerk"),
}
#: Those also compared between the evaluations with fresh candidate noise (``<key>_sampled``)
SAMPLED_PAIRS = ("offline_reward", "offline_jerk", "offline_jerk_per_step", "online_execution_rule")


def load_raw(paths: RunPaths, seeds: Sequence[int]) -> dict[str, dict[int, dict[str, Any]]]:
    """Per-seed raw results: ``{method: {seed: summary}}`` plus ``"style"`` (evaluation dicts)."""
    out: dict[str, dict[int, dict[str, Any]]] = {}
    for s in seeds:
        folder = paths.seed_raw(s)
        if not folder.is_dir():
            raise FileNotFoundError(f"no raw results for seed {s} in {folder}")
        for f in sorted(folder.glob("*.json")):
            payload = json.loads(f.read_text())
            out.setdefault(f.stem, {})[s] = payload if f.stem == "style" else payload["summary"]
        for f in sorted((folder / "online").glob("*.json")):
            out.setdefault(f"online/{f.stem}", {})[s] = json.loads(f.read_text())
    return out


def online_curve(episodes_per_seed: Sequence[Sequence[Mapping[str, Any]]], total_steps: int,
                 n_bins: int = 10) -> dict[str, list[float]]:
    """One arm's learning curve: the mean return of the episodes ending in each window of online steps."""
    edges = np.linspace(0, total_steps, n_bins + 1)
    per_seed = []
    for episodes in episodes_per_seed:
        ends = np.cumsum([e["length"] for e in episodes])
        rewards = np.array([e["reward"] for e in episodes], dtype=float)
        which = np.clip(np.searchsorted(edges, ends, side="left") - 1, 0, n_bins - 1)
        per_seed.append(
            [float(rewards[which == b].mean()) if np.any(which == b) else math.nan for b in range(n_bins)])
    values = np.array(per_seed, dtype=float).reshape(-1, n_bins)  # (seeds, bins)
    seen = np.isfinite(values).sum(axis=0)
    curve = np.where(seen > 0, np.nansum(values, axis=0) / np.maximum(seen, 1), np.nan)
    return {"steps": [float(x) for x in edges[1:]], "reward": [float(x) for x in curve]}


def online_phase_stats(episodes: Sequence[Mapping[str, Any]], last_fraction: float = 0.25) -> dict[str, float]:
    """Mean return and collision rate of one seed's Phase-2 training episodes, and the mean return of the last ones."""
    if not episodes:
        return {"reward": math.nan, "reward_last": math.nan, "collision": math.nan, "episodes": 0}
    last = episodes[-max(1, int(round(last_fraction * len(episodes)))) :]
    return {"reward": float(np.mean([e["reward"] for e in episodes])),
            "reward_last": float(np.mean([e["reward"] for e in last])),
            "collision": float(np.mean([e["collision"] for e in episodes])), "episodes": len(episodes)}


def _stats(per_seed: Mapping[int, Mapping[str, Any]], seeds: Sequence[int]) -> dict[str, Any]:
    out: dict[str, Any] = {"seeds": list(seeds)}
    for key in names.METRICS:  # a key missing from the raw data of an earlier version counts as NaN
        out[key] = t_summary([float(per_seed[s].get(key, math.nan)) for s in seeds])
    if all("length_shares" in per_seed[s] for s in seeds):  # the L_t histogram, recorded since 2026-12-04
        out["length_shares"] = np.mean([per_seed[s]["length_shares"] for s in seeds], axis=0).tolist()
    return out


def aggregate(raw: Mapping[str, Mapping[int, Mapping[str, Any]]], seeds: Sequence[int], budget: Fig2Budget,
              acting: Mapping[str, int] | None = None) -> dict[str, Any]:
    """Everything ``fig2.json`` holds, from the raw results of ``seeds`` (``acting``: the ``flow_steps`` and
    ``n_elite`` the checkpoints acted with by default, as the report recorded them)."""
    seeds = list(seeds)
    methods = _methods(raw, seeds)
    online_phases = _online_phases(raw, methods, seeds, budget)
    comparisons = _comparisons(methods, online_phases)
    result: dict[str, Any] = {
        **{paper_key: comparisons[key]["change_pct"] for paper_key, key in names.CLAIM_COMPARISONS.items()},
        "comparisons": comparisons, "paper": dict(names.PAPER), "methods": methods, "seeds": seeds,
        "relative_change_definition": "100 * (method - baseline) / |baseline|, on the means over seeds",
        "budget": budget.to_dict(), "online_phases": online_phases,
        **_style_summary(raw, seeds),
        "delta_sweep": _sweep(methods, "delta", budget.delta_sweep, lambda d: f"delta_{names.delta_name(d)}",
                              ("reward", "mean_executed_length", "cumulative_jerk")),
        "k_sweep": _sweep(methods, "k", budget.k_sweep, "k{}".format, ("reward", "cumulative_jerk", "collision")),
        **_acting_sweep(methods, budget, acting or {}),
    }
    training = _training_episodes(raw, seeds, budget)
    if training:
        result["online_phase"] = training
    if all(names.sampled_name(m) in methods for m in names.MAIN_METHODS):  # (a)-(c) with fresh candidate noise
        comparisons.update(_method_comparisons(methods, SAMPLED_PAIRS, "_sampled"))
        if {"adaptive_sampled", "fixed_sampled"} <= set(online_phases):  # pooled over the online phases, like (c)
            comparisons["online_reward_sampled"] = compare(online_phases["adaptive_sampled"]["per_seed"],
                                                           online_phases["fixed_sampled"]["per_seed"])
        result["sampled"] = {paper_key: comparisons.get(f"{key}_sampled", {}).get("change_pct", math.nan)
                             for paper_key, key in names.CLAIM_COMPARISONS.items()}
    if "adaptive_style" in methods:
        result["style_context"] = {"with": "adaptive_style", "without": "adaptive",
                                   "reward_gain_pct": _compare(methods, "adaptive_style", "adaptive", "reward")}
    return result


def _methods(raw: Mapping[str, Mapping[int, Mapping[str, Any]]], seeds: Sequence[int]) -> dict[str, Any]:
    """:func:`_stats` of every method evaluated on all ``seeds``; the four arms of (a)-(c) must be."""
    missing = [m for m in names.MAIN_METHODS if m not in raw or any(s not in raw[m] for s in seeds)]
    if missing:
        raise ValueError(f"raw results incomplete for method(s) {missing} and seeds {seeds}")
    return {m: _stats(raw[m], seeds) for m in raw
            if m != "style" and not m.startswith("online/") and all(s in raw[m] for s in seeds)}


def _per_seed(methods: Mapping[str, Any], method: str, key: str) -> list[float]:
    return methods[method][key]["per_seed"]


def _compare(methods: Mapping[str, Any], new: str, base: str, key: str) -> dict[str, Any]:
    """:func:`compare` of metric ``key`` of method ``new`` against method ``base``, seed by seed."""
    return compare(_per_seed(methods, new, key), _per_seed(methods, base, key))


def _comparisons(methods: Mapping[str, Any], online_phases: Mapping[str, Any]) -> dict[str, Any]:
    """(a)-(c), the comparisons behind the paper's numbers, and those beyond them the run's arms allow."""
    out = {**_method_comparisons(methods, METHOD_PAIRS),
           "online_reward": compare(online_phases["adaptive"]["per_seed"], online_phases["fixed"]["per_seed"])}
    episodes = online_phases["training_episodes"]
    if episodes:  # (c') and (c''), pooled over the online phases like (c)
        out["online_phase_reward"] = compare(episodes["adaptive"]["reward"], episodes["fixed"]["reward"])
        out["online_phase_reward_last"] = compare(episodes["adaptive"]["reward_last"], episodes["fixed"]["reward_last"])
    return out


def _method_comparisons(methods: Mapping[str, Any], keys: Iterable[str], suffix: str = "") -> dict[str, Any]:
    """The :data:`METHOD_PAIRS` of ``keys`` (their methods with ``suffix``) that have finite values on every seed."""
    out = {}
    for key in keys:
        new, base, metric = METHOD_PAIRS[key]
        pair = (new + suffix, base + suffix)
        if all(n in methods and all(math.isfinite(v) for v in _per_seed(methods, n, metric)) for n in pair):
            out[key + suffix] = _compare(methods, *pair, metric)
    return out


def _style_summary(raw: Mapping[str, Mapping[int, Any]], seeds: Sequence[int]) -> dict[str, Any]:
    """(d): the style classifier's accuracies and confusion matrix summed over seeds."""
    if not ("style" in raw and all(s in raw["style"] for s in seeds)):
        return {"style_macro_accuracy": math.nan}
    styles = [raw["style"][s] for s in seeds]
    macro = t_summary([float(r["macro_accuracy"]) for r in styles])
    matrix = np.sum([np.asarray(r["confusion_matrix"], dtype=np.int64) for r in styles], axis=0)
    return {"style_macro_accuracy": macro["mean"], "style": {
        "macro_accuracy": macro, "accuracy_per_seed": [float(r["accuracy"]) for r in styles],
        "baseline_macro_accuracy_per_seed": [float(r["baseline"]["macro_accuracy"]) for r in styles if "baseline" in r],
        "confusion_matrix": matrix.tolist(), "classes": styles[0]["classes"],
        "confusion_matrix_layout": "rows = inferred style, columns = ground truth, summed over seeds"}}


def _sweep(methods: Mapping[str, Any], field: str, values: Iterable[Any], method: Callable[[Any], str],
           keys: Sequence[str]) -> list[dict[str, Any]]:
    """The rows of a sweep over ``field`` (δ of the adaptive checkpoint, k of the chunk policies): the ``keys`` of
    each value's method that was evaluated."""
    return [{field: v, "method": method(v), **{k: methods[method(v)][k] for k in keys}}
            for v in values if method(v) in methods]


def _acting_sweep(methods: Mapping[str, Any], budget: Fig2Budget, acting: Mapping[str, int]) -> dict[str, Any]:
    """The offline checkpoints acting with each other rule (N, m), and how (a) and (b) act (``acting``: as recorded)."""
    default_n = int(acting.get("flow_steps") or budget.algo_kwargs.get("flow_steps", library_default("flow_steps")))
    default_elite = int(acting.get("n_elite") or budget.default_elite)
    rows = []
    for n, m in budget.acting_variants(default_elite):  # other acting rules for the offline checkpoints
        arms = {arm: names.acting_name(arm, n, m, default_elite) for arm in ("onestep", "chunk")}
        if not all(name in methods for name in arms.values()):
            continue
        rows.append({"flow_steps": default_n if n is None else n, "n_elite": m,
                     **{arm: {key: methods[name][key] for key in ("reward", "cumulative_jerk", "jerk_per_step",
                                                                  "collision")} for arm, name in arms.items()},
                     "jerk_change": _compare(methods, arms["chunk"], arms["onestep"], "cumulative_jerk"),
                     "reward_change": _compare(methods, arms["chunk"], arms["onestep"], "reward")})
    return {"acting_sweep": rows, "acting_default": {"flow_steps": default_n, "n_elite": default_elite}}


def _training_episodes(raw: Mapping[str, Mapping[int, Any]], seeds: Sequence[int], budget: Fig2Budget) -> dict[str, Any]:
    """Per logged arm (first online phase), its :func:`online_phase_stats` over seeds and its learning curve."""
    out: dict[str, Any] = {}
    for arm in names.ONLINE_ARMS:
        logs = raw.get(f"online/{arm}", {})
        if not all(s in logs for s in seeds):
            continue
        rows = [online_phase_stats(logs[s]["episodes"]) for s in seeds]
        out[arm] = {key: t_summary([r[key] for r in rows]) for key in ("reward", "reward_last", "collision", "episodes")}
        out[arm]["curve"] = online_curve([logs[s]["episodes"] for s in seeds], budget.finetune_steps)
    return out


def _online_phases(raw: Mapping[str, Mapping[int, Any]], methods: Mapping[str, Any], seeds: Sequence[int],
                   budget: Fig2Budget) -> dict[str, Any]:
    """The online phases pooled into (c) (those whose two arms were evaluated on every seed), (c) within each, and
    both arms' pooled per-run rewards."""
    phases = [r for r in range(budget.online_replicates)
              if all(names.replicate_name(arm, r) in methods for arm in ("adaptive", "fixed"))]

    def rewards(arm: str, suffix: str = "") -> list[float]:
        return [v for r in phases for v in _per_seed(methods, names.replicate_name(arm, r) + suffix, "reward")]

    out: dict[str, Any] = {"phases": list(phases), "runs": len(phases) * len(seeds), "per_phase": []}
    for r in phases:
        adaptive, fixed = names.replicate_name("adaptive", r), names.replicate_name("fixed", r)
        row: dict[str, Any] = {"phase": r, "adaptive": methods[adaptive]["reward"], "fixed": methods[fixed]["reward"],
                               "change": _compare(methods, adaptive, fixed, "reward")}
        sampled = names.sampled_name(adaptive), names.sampled_name(fixed)
        if all(n in methods for n in sampled):
            row["change_sampled"] = _compare(methods, *sampled, "reward")
        out["per_phase"].append(row)
    for arm in ("adaptive", "fixed"):
        for suffix in ("", "_sampled"):
            if suffix and not all(names.sampled_name(names.replicate_name(arm, r)) in methods for r in phases):
                continue
            out[arm + suffix] = t_summary(rewards(arm, suffix))  # per run
    logs = {arm: [raw.get(f"online/{names.replicate_name(arm, r)}", {}).get(s) for r in phases for s in seeds]
            for arm in ("adaptive", "fixed")}
    out["training_episodes"] = {}
    if phases and all(log is not None for runs in logs.values() for log in runs):
        for arm, runs in logs.items():
            stats = [online_phase_stats(log["episodes"]) for log in runs]
            out["training_episodes"][arm] = {key: [st[key] for st in stats] for key in ("reward", "reward_last")}
    return out
