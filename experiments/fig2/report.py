"""The Figure-2 report: ``fig2.md`` (one builder per section), ``fig2.json`` and the PNG panels."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from envs.style import plot_confusion
from experiments.common import names, records
from experiments.common.records import figure, section, table
from experiments.common.stats import interval, t_summary
from experiments.fig2.budget import STAGES, RunPaths
from sb3_ua2c.execution import format_length_shares

Lines = list[str]


def _fmt(stat: Mapping[str, Any], digits: int = 2) -> str:
    mean, half = stat["mean"], stat["ci95"]
    if not math.isfinite(mean):
        return "n/a"
    return f"{mean:.{digits}f}" + ("" if not math.isfinite(half) else f" ± {half:.{digits}f}")


def format_pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{x:+.2f}%"


def paper_verdict(paper_key: str, change_pct: float) -> str:
    """``"at or beyond"`` when our relative change is at least as good as the paper's, else ``"short"``."""
    better_is_lower = paper_key == "offline_jerk_change_pct"
    ours, paper = float(change_pct), names.PAPER[paper_key]
    ok = ours <= paper if better_is_lower else ours >= paper
    return "at or beyond" if ok else "short"


def format_markdown(summary: Mapping[str, Any], command: str, date: str) -> str:
    """``fig2.md``: headline comparison with the paper, per-method table, style, sweeps."""
    sections = (_header(summary, command, date), _claims_table(summary), _methods_table(summary),
                _online_phases_table(summary), _training_episodes_table(summary), _style_section(summary),
                _delta_sweep_table(summary), _k_sweep_table(summary), _acting_sweep_table(summary),
                _style_context_section(summary), _budget_section(summary), _compute_table(summary))
    return "\n".join([line for part in sections for line in part] + [""])


def _n_phases(summary: Mapping[str, Any]) -> int:
    return len(summary.get("online_phases", {}).get("phases", [0]))


def _header(summary: Mapping[str, Any], command: str, date: str) -> Lines:
    return [
        "# Figure 2 reproduction on MixedTraffic-v0",
        "",
        f"Command: `{command}`  ",
        f"Date: {date}  ",
        f"Seeds: {summary['seeds']} (means ± 95% Student-t intervals over {len(summary['seeds'])} seed(s); "
        "a single seed has no interval)",
        "",
        "Relative change = 100 · (method − baseline) / |baseline|, applied to the means over seeds; "
        "the per-seed column is the mean ± 95% interval of the per-seed changes, and the paired difference is "
        "the mean per-run difference method − baseline in the metric's units with its 95% Student-t interval "
        "(the runs of a seed share its data and scenarios; an interval that contains 0 shows no difference). "
        "Where a claim is short of the paper, docs/research-log.md (\"What was tried\") says what was tried. "
        "Rows without a suffix act with fixed candidate noise (`predict(deterministic=True)`: the same "
        "history always gives the same plan); rows marked \"sampled\" evaluate the same checkpoints "
        "drawing fresh candidate noise at every replanning, as the rollouts of Phase 2 do (seeded per episode).",
        "",
    ]


def _claim_rows(summary: Mapping[str, Any]) -> tuple[tuple[str, str, str | None], ...]:
    """``(label, comparisons key, PAPER key or None)`` of the claims table, in order: (a)-(c), the
    variants beyond the paper, then the "sampled" rows of (a)-(c), (b'') and (c''')."""
    n_phases = _n_phases(summary)
    pooled = f" ({len(summary['seeds'])} seeds × {n_phases} online phases, pooled)" if n_phases > 1 else ""
    rows = (("(a) offline reward, chunk vs one-step", "offline_reward", "offline_reward_gain_pct"),
            ("(b) cumulative jerk, chunk vs one-step", "offline_jerk", "offline_jerk_change_pct"),
            (f"(c) online reward, adaptive vs fixed{pooled}", "online_reward", "online_reward_gain_pct"))
    extra = (
        ("(a') offline reward, chunk with adaptive execution vs one-step", "offline_reward_chunk_adaptive", None),
        ("(b') cumulative jerk, chunk with adaptive execution vs one-step", "offline_jerk_chunk_adaptive", None),
        ("(b'') jerk per step (Σ\\|jerk\\| / episode length), chunk vs one-step", "offline_jerk_per_step", None),
        (f"(c') online reward during Phase 2 (mean return of the training episodes), adaptive vs fixed{pooled}",
         "online_phase_reward", None),
        (f"(c'') the same over the last quarter of the training episodes{pooled}", "online_phase_reward_last", None),
        ("(c''') the execution rule alone: the fixed arm's checkpoint executed adaptively vs with fixed chunks"
         + (" (first online phase)" if pooled else ""), "online_execution_rule", None),
    )
    sampled = tuple(
        (f"{label} — sampled", f"{key}_sampled", paper_key) for label, key, paper_key in (*rows, extra[2], extra[5]))
    return (*rows, *extra, *sampled)


def _claims_table(summary: Mapping[str, Any]) -> Lines:
    """The headline table: our relative change of each claim next to the paper's."""
    c = summary["comparisons"]
    rows = []
    for label, key, paper_key in _claim_rows(summary):
        if key not in c:
            continue
        cmp, paired = c[key], c[key].get("paired")
        per_seed = _fmt({"mean": cmp["per_seed_mean_pct"], "ci95": cmp["per_seed_ci95_pct"]}) + "%"
        diff = f"{interval(paired)} ({paired['x_better_runs']} of {paired['runs']} runs higher)" if paired else ""
        paper = "not in the paper" if paper_key is None else f"{names.PAPER[paper_key]:+.2f}%"
        verdict = "" if paper_key is None else paper_verdict(paper_key, cmp["change_pct"])
        rows.append([label, format_pct(cmp["change_pct"]), per_seed, diff, paper, verdict])
    lines = table(["claim", "ours", "per-seed changes", "paired difference [95 % CI]", "paper", "vs paper"], rows)
    if summary.get("style"):
        lines.append(f"| (d) style inference, macro accuracy | {_fmt(summary['style']['macro_accuracy'], 3)} | | "
                     "confusion matrix only | |")
    return lines


def _methods_table(summary: Mapping[str, Any]) -> Lines:
    """Every metric of the main methods (and their "sampled" evaluations), mean ± interval over seeds."""
    methods = [m for m in names.METHOD_LABELS if m in summary["methods"]]  # in the order of the labels
    lines = section("Methods", *table(
        ["method", "reward", "cum. jerk", "jerk per step", "collision rate", "merge success", "mean speed [m/s]",
         "mean L_t"],
        ([names.METHOD_LABELS[m], *(_fmt(summary["methods"][m][k], 1 if k == "cumulative_jerk" else 2)
                                    for k in names.METRICS)] for m in methods)))
    shares = [[names.METHOD_LABELS[m], format_length_shares(summary["methods"][m]["length_shares"])] for m in methods
              if "length_shares" in summary["methods"][m]]
    if shares:
        lines += ["", "Executed lengths (share of plans with L_t = 1..k, %, mean over seeds):", "",
                  *table(["method", "L_t = 1..k"], shares)]
    return lines


def _online_phases_table(summary: Mapping[str, Any]) -> Lines:
    """(c) within each online phase and pooled (only with more than one phase)."""
    if _n_phases(summary) <= 1:
        return []
    c, op = summary["comparisons"], summary["online_phases"]
    offset = summary["budget"].get("online_seed_offset", 0)
    rows = [[offset + row["phase"], _fmt(row["fixed"]), _fmt(row["adaptive"]), format_pct(row["change"]["change_pct"]),
             format_pct(row["change_sampled"]["change_pct"]) if "change_sampled" in row else ""]
            for row in op["per_phase"]]
    rows.append([f"pooled ({op['runs']} runs)", _fmt(op["fixed"]), _fmt(op["adaptive"]),
                 format_pct(c["online_reward"]["change_pct"]),
                 format_pct(c["online_reward_sampled"]["change_pct"]) if "online_reward_sampled" in c else ""])
    return section(
        "(c) per online phase (both arms fine-tuned again from the same pre-trained checkpoint)",
        "The methods table and the Phase-2 table show the first online phase; (c), (c') and (c'') pool "
        f"the {op['runs']} paired runs of all phases. Phase r runs seed s with "
        f"s + {names.MAX_SEED} × (online_seed_offset + r).",
        "",
        *table(["online phase", "fixed", "adaptive", "(c)", "(c) sampled"], rows))


def _training_episodes_table(summary: Mapping[str, Any]) -> Lines:
    """The Phase-2 training episodes of each logged arm (first online phase)."""
    if not summary.get("online_phase"):
        return []
    return section(
        "Phase 2: the training episodes (candidates drawn with fresh noise, as during training)"
        + (", first online phase" if _n_phases(summary) > 1 else ""),
        *table(["arm", "mean return", "mean return, last quarter", "collision rate", "episodes"],
               ([names.METHOD_LABELS[arm], _fmt(st["reward"]), _fmt(st["reward_last"]), _fmt(st["collision"]),
                 _fmt(st["episodes"], 1)] for arm, st in summary["online_phase"].items())))


def _style_section(summary: Mapping[str, Any]) -> Lines:
    """(d): the confusion matrix summed over seeds and the logistic-regression baseline."""
    style = summary.get("style")
    if not style:
        return []
    lines = section("(d) Driving-style inference", f"Confusion matrix ({style['confusion_matrix_layout']}):", "",
                     *table(["inferred \\ truth", *style["classes"]],
                            ([name, *row] for name, row in zip(style["classes"], style["confusion_matrix"], strict=True))))
    if style["baseline_macro_accuracy_per_seed"]:
        base = t_summary(style["baseline_macro_accuracy_per_seed"])
        lines += ["", f"Logistic-regression baseline on summary features: macro accuracy {_fmt(base, 3)}."]
    return lines


def _delta_sweep_table(summary: Mapping[str, Any]) -> Lines:
    rows = [[f"{row['delta']:g}", _fmt(row["mean_executed_length"]), _fmt(row["reward"]), _fmt(row["cumulative_jerk"], 1)]
            for row in summary["delta_sweep"]]
    return section("δ sweep (fine-tuned adaptive checkpoint, execution threshold only)",
                    *table(["δ", "mean L_t", "reward", "cum. jerk"], rows)) if rows else []


def _k_sweep_table(summary: Mapping[str, Any]) -> Lines:
    rows = [[row["k"], _fmt(row["reward"]), _fmt(row["cumulative_jerk"], 1), _fmt(row["collision"])]
            for row in summary["k_sweep"]]
    return section("k sweep (offline, same data and gradient budget, full chunks)",
                    *table(["k", "reward", "cum. jerk", "collision rate"], rows)) if rows else []


def _acting_sweep_table(summary: Mapping[str, Any]) -> Lines:
    """The offline checkpoints acting with other Euler steps N and elite sizes m."""
    if not summary.get("acting_sweep"):
        return []
    default = summary.get("acting_default", {"n_elite": 1})
    rows = [[row["flow_steps"], row["n_elite"], _fmt(row["onestep"]["reward"]), _fmt(row["chunk"]["reward"]),
             _fmt(row["onestep"]["cumulative_jerk"], 1), _fmt(row["chunk"]["cumulative_jerk"], 1),
             format_pct(row["jerk_change"]["change_pct"]), _fmt(row["chunk"]["jerk_per_step"]),
             _fmt(row["chunk"]["collision"])] for row in summary["acting_sweep"]]
    return section(
        "Acting rule (offline checkpoints, full chunks): N Euler steps of the sampler, elite mean of "
        f"the m best candidates (`flow_steps`, `n_elite`); (a) and (b) act with the checkpoints' N and "
        f"m = {default['n_elite']}",
        *table(["N", "m", "one-step reward", "chunk reward", "one-step cum. jerk", "chunk cum. jerk", "jerk change",
                "chunk jerk per step", "chunk collision rate"], rows))


def _style_context_section(summary: Mapping[str, Any]) -> Lines:
    if "style_context" not in summary:
        return []
    cmp = summary["style_context"]["reward_gain_pct"]
    per_seed = _fmt({"mean": cmp["per_seed_mean_pct"], "ci95": cmp["per_seed_ci95_pct"]})
    return section("Style context c_t (Eq. 6) in the observation",
                    f"Adaptive arm with vs without c_t (own dataset, same budgets): reward change "
                    f"{format_pct(cmp['change_pct'])} (per seed {per_seed}%).")


def _budget_section(summary: Mapping[str, Any]) -> Lines:
    b = summary["budget"]
    phases = f" in each of {b['online_replicates']} online phases" if b.get("online_replicates", 1) > 1 else ""
    onestep = f"; one-step baseline {b['onestep_kwargs']}" if b.get("onestep_kwargs") else ""
    phase2 = f"; Phase 2 {b['finetune_kwargs']}" if b.get("finetune_kwargs") else ""
    offset = b.get("online_seed_offset")
    offset = f"; Phase 2 seeds offset by {names.MAX_SEED} × {offset}" if offset else ""
    return section(
        "Budget (per seed)",
        f"{b['dataset_episodes']} offline episodes; {b['pretrain_steps']} gradient steps per pre-trained arm; "
        f"{b['finetune_steps']} online steps per fine-tuned arm{phases}; {b['eval_episodes']} evaluation "
        f"episode(s) per method and seed; k = {b['chunk_size']}, δ = {b['entropy_threshold']:g}; "
        f"env {b['env_kwargs'] or 'defaults'}; UA2C {b['algo_kwargs'] or 'defaults'}{onestep}{phase2}{offset}.")


def _compute_table(summary: Mapping[str, Any]) -> Lines:
    """Measured against estimated compute per stage (only when units were timed)."""
    seconds = summary.get("seconds", {})
    if not seconds.get("measured"):
        return []
    measured, estimated = seconds["measured"], seconds.get("estimated", {})
    listed = [k for k in STAGES if k in estimated] + [k for k in estimated if k not in (*STAGES, "total")]
    rows = [[stage, "n/a" if measured.get(stage) is None else f"{measured[stage] / 60:.1f}",
             f"{estimated.get(stage, math.nan) / 60:.1f}"] for stage in (*listed, "total")]
    return ["", "Compute, summed over seeds (one worker = one core; measured = units run by the calls "
            "that built these results):", "", *table(["stage", "measured [min]", "estimated [min]"], rows)]


#: Bar panels of (a)-(c): file name, title, y label, arms (baseline first), metric, PAPER key.
CLAIM_PANELS = (
    ("fig2_a_offline_reward.png", "(a) offline reward", "episode reward", ("onestep", "chunk"), "reward",
     "offline_reward_gain_pct"),
    ("fig2_b_offline_jerk.png", "(b) offline cumulative jerk", "Σ|jerk| [m/s³]", ("onestep", "chunk"),
     "cumulative_jerk", "offline_jerk_change_pct"),
    ("fig2_c_online_reward.png", "(c) online reward", "episode reward", ("fixed", "adaptive"), "reward",
     "online_reward_gain_pct"),
)
_SHORT_LABELS = {"onestep": "one-step", "chunk": "chunk", "fixed": "fixed", "adaptive": "adaptive"}


def _claim_panels(summary: Mapping[str, Any]) -> list[tuple[str, str, str, list[tuple[str, Any]], str]]:
    """Arguments of :func:`bar_panel` for (a)-(c), then for their "sampled" evaluations."""
    methods, op = summary["methods"], summary.get("online_phases", {})
    suffixes = ("", "_sampled") if "sampled" in summary else ("",)
    panels = []
    for suffix in suffixes:
        for name, title, ylabel, arms, metric, paper_key in CLAIM_PANELS:
            if suffix:
                name, title = name.replace(".png", "_sampled.png"), f"{title}, sampled"
            ours = (summary["sampled"] if suffix else summary)[paper_key]  # the change_pct of the claim's comparison
            stats = {a: methods[a + suffix][metric] for a in arms}
            if paper_key == "online_reward_gain_pct" and len(op.get("phases", [0])) > 1:  # every pooled run
                stats, title = {a: op[a + suffix] for a in arms}, f"{title}, {op['runs']} runs"
            note = f"ours {format_pct(ours)}, paper {names.PAPER[paper_key]:+.2f}%"
            panels.append((name, title, ylabel, [(_SHORT_LABELS[a], stats[a]) for a in arms], note))
    return panels


def write_report(summary: Mapping[str, Any], paths: RunPaths, command: str, date: str) -> list[Path]:
    """Write ``fig2.json``, ``fig2.md`` and the PNG panels into ``paths.out``; return the files."""
    return records.write_report(paths.out, "fig2", {**summary, "command": command, "date": date},
                                format_markdown(summary, command, date), lambda out: write_panels(summary, out))


def write_panels(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """The PNG panels of a report: (a)-(c) as bars, (d)'s confusion matrix, the online curves and the sweeps."""
    files = [bar_panel(out / name, *panel) for name, *panel in _claim_panels(summary)]
    if "style" in summary:
        st = summary["style"]
        plot_confusion(np.asarray(st["confusion_matrix"]), out / "fig2_d_style_confusion.png", st["classes"],
                       title=f"(d) driving style, macro acc {_fmt(st['macro_accuracy'], 3)}")
        files.append(out / "fig2_d_style_confusion.png")
    if summary.get("online_phase"):
        files.append(curve_panel(out / "fig2_c_online_curves.png", summary))
    if summary["delta_sweep"] or summary["k_sweep"]:
        files.append(sweep_panel(out / "fig2_sweeps.png", summary))
    return files


def bar_panel(path: Path, title: str, ylabel: str, arms: Sequence[tuple[str, Mapping[str, Any]]], note: str) -> Path:
    with figure(path, (4.2, 3.6)) as fig:
        ax = fig.add_subplot()
        for i, (_label, stat) in enumerate(arms):
            half = stat["ci95"] if math.isfinite(stat["ci95"]) else 0.0
            ax.bar(i, stat["mean"], yerr=half, capsize=6, color=("#9e9e9e", "#1f77b4")[i % 2], alpha=0.85)
            ax.scatter(np.full(len(stat["per_seed"]), i) + np.linspace(-0.15, 0.15, len(stat["per_seed"])),
                       stat["per_seed"], color="black", s=12, zorder=3)
        ax.set_xticks(range(len(arms)), [a[0] for a in arms])
        ax.set_ylabel(ylabel)
        ax.set_title(f"{title}\n{note}", fontsize=9)
    return path


def sweep_panel(path: Path, summary: Mapping[str, Any]) -> Path:
    with figure(path, (8.4, 3.6)) as fig:
        ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
        for row in summary["delta_sweep"]:
            x, y = row["mean_executed_length"], row["reward"]
            ax1.errorbar(x["mean"], y["mean"], xerr=np.nan_to_num(x["ci95"]), yerr=np.nan_to_num(y["ci95"]), fmt="o")
            ax1.annotate(f"δ={row['delta']:g}", (x["mean"], y["mean"]), fontsize=7, xytext=(3, 3),
                         textcoords="offset points")
        ax1.set_xlabel("mean executed length L_t")
        ax1.set_ylabel("episode reward")
        ax1.set_title("δ sweep (adaptive checkpoint)", fontsize=9)
        ks = summary["k_sweep"]
        if ks:
            ax2.errorbar([r["k"] for r in ks], [r["reward"]["mean"] for r in ks],
                         yerr=[np.nan_to_num(r["reward"]["ci95"]) for r in ks], fmt="o-")
        ax2.set_xlabel("chunk length k")
        ax2.set_ylabel("offline episode reward")
        ax2.set_title("k sweep (same gradient budget)", fontsize=9)
    return path


def curve_panel(path: Path, summary: Mapping[str, Any]) -> Path:
    with figure(path, (5.2, 3.6)) as fig:
        ax = fig.add_subplot()
        for arm, st in summary["online_phase"].items():
            curve = st["curve"]
            ax.plot(curve["steps"], curve["reward"], "o-", label=names.METHOD_LABELS[arm], markersize=3)
        ax.set_xlabel("online environment steps")
        ax.set_ylabel("training episode return")
        ax.set_title(f"(c) Phase 2 training episodes, mean over {len(summary['seeds'])} seed(s)", fontsize=9)
        ax.legend(fontsize=7)
    return path
