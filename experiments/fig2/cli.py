"""Command line of the Figure-2 runner (``python -m experiments fig2``)."""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path

from experiments.common.cli import harness_main, harness_parent, select_seeds
from experiments.common.names import PAPER
from experiments.common.records import run_header
from experiments.fig2.aggregation import aggregate, load_raw
from experiments.fig2.budget import (
    FULL_BUDGET,
    QUICK_BUDGET,
    Fig2Budget,
    RunPaths,
    estimate_seconds,
    estimate_wall_seconds,
)
from experiments.fig2.report import format_pct, write_report
from experiments.fig2.units import SEED_PARTS, measured_seconds, run_all
from sb3_ua2c.checks import check_int


def recorded_budget(report: str | os.PathLike) -> Fig2Budget:
    """The budget of a ``fig2.json`` or of the directory holding it (newer fields take their defaults)."""
    path = Path(report) / "fig2.json" if Path(report).is_dir() else Path(report)
    try:
        recorded = json.loads(path.read_text())["budget"]
    except FileNotFoundError:
        raise ValueError(f"--budget-of: {path} does not exist") from None
    except (json.JSONDecodeError, TypeError, KeyError) as exc:
        raise ValueError(f"--budget-of: {path} is not a fig2.json with a 'budget' key ({exc!r})") from exc
    return Fig2Budget.from_dict(recorded)


PROG = "python -m experiments fig2"
PARENT = harness_parent(
    seeds="0 1 2 3 4", work="<out>/fig2_work",
    workers_help="units run in parallel processes, two per seed: its main and style parts (default: 2)",
    quick="tiny budget (4-s episodes, a few updates): a smoke test",
    budget="Fig2Budget overrides as JSON, e.g. '{\"pretrain_steps\": 4000}'", raw="<out>/fig2_raw")


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, parents=[PARENT],
        description="Reproduce the UA2C paper's Figure 2 (a)-(d) on MixedTraffic-v0 over several seeds, with the "
        "δ, k and style-context sweeps. Resumable: finished units (datasets, checkpoints, evaluations) are skipped.",
    )
    parser.add_argument("--seed-list", dest="seeds", type=int, nargs="+", help="the same as --seeds")
    parser.add_argument("--budget-of", default=None, metavar="REPORT",
                        help="start from the budget a report ran with (its fig2.json, or the directory holding it) "
                        "instead of the default; --budget applies on top. Reruns a report made under another default "
                        "exactly")
    return parser


def _check(args: argparse.Namespace) -> tuple[list[int], Fig2Budget]:
    if args.budget_of is not None and args.quick:
        raise ValueError("--budget-of and --quick both choose the base budget: pass one of them")
    base = recorded_budget(args.budget_of) if args.budget_of is not None else QUICK_BUDGET if args.quick else FULL_BUDGET
    seeds = select_seeds(args.seeds, range(5))
    check_int("--workers", args.workers)
    return seeds, base.replace(**args.budget) if args.budget else base


def _run_units(args: argparse.Namespace, seeds: list[int], budget: Fig2Budget, paths: RunPaths) -> dict[str, float]:
    """Run the units not stored yet; the estimate printed first."""
    est = estimate_seconds(budget, len(seeds))
    workers = min(args.workers, len(SEED_PARTS) * len(seeds))
    wall = estimate_wall_seconds(est, len(seeds), workers)
    print(f"Figure 2: seeds {seeds}, {workers} worker(s); estimated {est['total'] / 60:.1f} CPU-min, ~{wall / 60:.0f} "
          "min wall before resuming (" + ", ".join(f"{k} {v / 60:.1f}" for k, v in est.items() if k != "total")
          + " CPU-min)", flush=True)
    t0 = time.perf_counter()
    executed = run_all(seeds, budget, paths, workers, ray_address=args.ray_address)
    print(f"{len(executed)} unit(s) run in {time.perf_counter() - t0:.0f} s", flush=True)
    return est


def _run(args: argparse.Namespace, checked: tuple[list[int], Fig2Budget], command: str) -> int:
    seeds, budget = checked
    paths = RunPaths.under(args.out, args.raw, args.work)
    command, date, recorded = run_header(command, paths.out / "fig2.json", args.report_only)
    est = None if args.report_only else _run_units(args, seeds, budget, paths)
    acting = {}
    if args.report_only:
        # without the run's manifest, fig2.json gives the N and n_elite its checkpoints acted with where the budget
        # left them to the library (whose defaults may have changed)
        if paths.recorded_budget() is None:
            acting = recorded.get("acting_default", {})
        budget = paths.rebuilt_budget(recorded, budget)
    summary = aggregate(load_raw(paths, seeds), seeds, budget, acting)
    seconds = recorded.get("seconds", {})
    summary["seconds"] = {
        # without the work directory (e.g. a fresh clone), the timings recorded with the run
        "measured": measured_seconds(paths, seeds) or seconds.get("measured", {}),
        # a rebuilt report keeps the estimate printed before its run
        "estimated": seconds.get("estimated") or est or estimate_seconds(budget, len(seeds)),
    }
    files = write_report(summary, paths, command, date)
    for label, key in (("offline reward", "offline_reward_gain_pct"), ("offline jerk", "offline_jerk_change_pct"),
                       ("online reward", "online_reward_gain_pct")):
        print(f"{label}: ours {format_pct(summary[key])}, paper {PAPER[key]:+.2f}%")
    print(f"style macro accuracy: {summary['style_macro_accuracy']:.3f}")
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument or missing results, 1 when units failed)."""
    return harness_main(build_parser(prog), argv, prog, _check, _run)
