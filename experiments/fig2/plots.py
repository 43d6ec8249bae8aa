"""Matplotlib panels of the Figure-2 report."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common.names import METHOD_LABELS
from experiments.common.records import figure


def bar_panel(path: Path, title: str, ylabel: str, arms: Sequence[tuple[str, Mapping[str, Any]]], note: str) -> None:
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


def sweep_panel(path: Path, summary: Mapping[str, Any]) -> None:
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


def curve_panel(path: Path, summary: Mapping[str, Any]) -> None:
    with figure(path, (5.2, 3.6)) as fig:
        ax = fig.add_subplot()
        for arm, st in summary["online_phase"].items():
            curve = st["curve"]
            ax.plot(curve["steps"], curve["reward"], "o-", label=METHOD_LABELS[arm], markersize=3)
        ax.set_xlabel("online environment steps")
        ax.set_ylabel("training episode return")
        ax.set_title(f"(c) Phase 2 training episodes, mean over {len(summary['seeds'])} seed(s)", fontsize=9)
        ax.legend(fontsize=7)
