"""Pool claim (c) over replicates of the online phase (``Fig2Budget.online_seed_offset``):
``python -m experiments pool-replicates REPORT [REPORT ...] [--sampled]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from experiments.common.names import PAPER
from experiments.common.stats import relative_change_pct, t_confidence_interval
from experiments.fig2.compare_runs import c_runs


def describe(name: str, pairs: list[tuple[float, float]]) -> str:
    adaptive, fixed = np.array(pairs).T
    per_run = [relative_change_pct(a, f) for a, f in pairs]
    mean, half = t_confidence_interval(per_run)
    return (f"| {name} | {len(pairs)} | {adaptive.mean():.1f} | {fixed.mean():.1f} | "
            f"{relative_change_pct(adaptive.mean(), fixed.mean()):+.2f} % | {mean:+.1f} ± {half:.1f} % |")


def main(argv: list[str] | None = None, prog: str | None = None) -> None:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("reports", nargs="+", type=Path)
    parser.add_argument("--sampled", action="store_true", help="pool the evaluations with fresh candidate noise")
    args = parser.parse_args(argv)
    runs = {report: c_runs(report, "_sampled" if args.sampled else "") for report in args.reports}
    empty = [report for report, by_seed in runs.items() if not by_seed]
    if empty:
        raise SystemExit(f"error: no fig2_raw/seed*/ results under {empty[0]}")
    seeds = {tuple(sorted({seed for seed, _ in r})) for r in runs.values()}
    if len(seeds) != 1:
        raise SystemExit(f"error: the reports hold different seeds: {sorted(seeds)}")
    print("| report | runs | adaptive | fixed | (c) change of the means | per-run changes |")
    print("|---|---|---|---|---|---|")
    pooled = []
    for report, by_seed in runs.items():
        print(describe(str(report), list(by_seed.values())))
        pooled += list(by_seed.values())
    print(describe("pooled", pooled))
    print(f"paper: {PAPER['online_reward_gain_pct']:+.2f} %")
