"""Command line of the head-to-head: ``python -m experiments peers`` (see ``docs/peers.md``)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from experiments.common.cli import check_extras, harness_main, harness_parent, select_seeds
from experiments.common.names import SCENARIO_BASES
from experiments.common.records import run_header
from experiments.common.runner import make_executor, ray_session
from experiments.peers.budget import (
    ARMS,
    D3RLPY_ARMS,
    FULL_PEERS_BUDGET,
    QUICK_PEERS_BUDGET,
    PeersBudget,
    estimate_units,
    format_estimate,
)
from experiments.peers.report import aggregate, verdicts, write_report
from experiments.peers.runner import PeersPaths, load_records, run_peers
from sb3_ua2c.checks import check_int

PROG = "python -m experiments peers"
PARENT = harness_parent(
    seeds="0 1 2 3 4; with --quick: 0 1", work="<out>/peers_work", workers=None,
    workers_help="local processes at once, each unit in a fresh process (default: 2; with --quick: 1); 1 runs the "
    "units one after the other in this process",
    quick="tiny budget (4-s episodes, a few updates) and 200 bootstrap replications: a smoke test",
    budget="PeersBudget overrides as JSON, on top of the default (or --quick) budget; \"ua2c\" overrides Fig2Budget "
    "keys one by one, e.g. '{\"rlpd_updates_per_step\": 8, \"ua2c\": {\"algo_kwargs\": {\"q_weight\": 0.5}}}' "
    "(a tuning configuration), or @FILE for a JSON file (the tuning's selected.json)",
    raw="<out>/peers_raw", scenarios=True, rerun=True)


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, parents=[PARENT],
        description="Head-to-head on MixedTraffic-v0: UA2C (Figure 2's adaptive, fixed and one-step arms) against "
        "SB3 SAC, sb3-contrib TQC and CrossQ, SAC with the offline data, d3rlpy IQL, Cal-QL and ReBRAC, and a "
        "d3rlpy BC reference row, on the Figure-2 protocol. "
        "Resumable: every (arm, seed) is a unit with its own result file; stored units are skipped. The report "
        "covers every record under --raw, whatever --seeds and --arms select to run.",
    )
    parser.add_argument("--arms", nargs="+", default=list(ARMS), metavar="ARM",
                        help=f"arms to run (default: all): {' '.join(ARMS)}")
    parser.add_argument("--online-steps", type=int, default=None,
                        help=f"online env steps of every arm (default {FULL_PEERS_BUDGET.online_steps})")
    parser.add_argument("--snapshot-every", type=int, default=0, metavar="STEPS",
                        help="also save each UA2C arm every STEPS online steps (<work>/seed<s>/<arm>/snapshots/; the "
                        "frozen checkpoints of `python -m experiments acting`); default 0: only the final model")
    return parser


def check_arms(arms: Sequence[str]) -> list[str]:
    """The known arms of ``arms``, in :data:`ARMS`' order (a ``ValueError`` names an unknown one)."""
    unknown = [a for a in arms if a not in ARMS]
    if unknown:
        raise ValueError(f"--arms: unknown arm(s) {unknown}; choose from {list(ARMS)}")
    return [a for a in ARMS if a in arms]


def needed_extras(arms: Sequence[str], report_only: bool) -> list[str]:
    """The optional modules a run needs: rliable for the report, d3rlpy for its arms."""
    return ["rliable", *([] if report_only or not set(arms) & set(D3RLPY_ARMS) else ["d3rlpy", "structlog"])]


def _budget(args: argparse.Namespace) -> PeersBudget:
    budget = dataclasses.replace((QUICK_PEERS_BUDGET if args.quick else FULL_PEERS_BUDGET).with_overrides(args.budget),
                                 scenarios=args.scenarios)
    return budget if args.online_steps is None else budget.with_online_steps(args.online_steps)


def scenario_text(records: dict[str, list[dict[str, Any]]]) -> str:
    """Which evaluation scenarios the records used, from their seeds (base = evaluation seed - run seed)."""
    names = {base: name for name, base in SCENARIO_BASES.items()}
    bases = sorted({r["eval_seeds"][0] - r["seed"] for rs in records.values() for r in rs})
    return ", ".join(f"{names.get(b, 'unknown')} scenarios (SUMO seeds 1000 · ({b} + seed) + i)" for b in bases)


def observation_text(records: dict[str, list[dict[str, Any]]]) -> str:
    """What the arms observe, from their records' environment (with or without the style context c_t)."""
    classifiers = {r["env"].get("style_classifier") for rs in records.values() for r in rs}
    if classifiers == {None}:
        return "the raw 20-number observation, WITHOUT the driving-style context c_t (as Figure 2's main arms)"
    return f"the observation with the driving-style context c_t (classifier {sorted(map(str, classifiers))})"


def reused_records(records: dict[str, list[dict[str, Any]]], work: Path) -> dict[str, list[str]]:
    """Arms whose records another run made (their dataset lies outside ``work``): ``{that run's work: arms}``."""
    reused: dict[str, set[str]] = {}
    work = work.resolve()
    for arm, rs in records.items():
        for r in rs:
            dataset = Path(r["dataset"]["path"])  # <work>/seed<N>/dataset
            if not dataset.resolve().is_relative_to(work):
                reused.setdefault(dataset.parent.parent.as_posix(), set()).add(arm)
    return {run: sorted(arms) for run, arms in sorted(reused.items())}


def build_summary(paths: PeersPaths, budget: PeersBudget, workers: int, command: str, date: str,
                  reps: int = 2000, estimate: dict[str, Any] | None = None) -> dict[str, Any]:
    """``peers.json``: its header and :func:`~experiments.peers.report.aggregate`."""
    records = load_records(paths)
    summary = aggregate(records, reps)
    seeds = sorted({s for arm in summary["arms"].values() for s in arm["seeds"]})
    reused = reused_records(records, paths.work)
    elsewhere = {a for arms in reused.values() for a in arms}
    if estimate is None:
        estimate = estimate_units(budget, [a for a in summary["arms"] if a in ARMS and a not in elsewhere], len(seeds),
                                  workers)
    return {"command": command, "date": date, "seeds": seeds, "budget": budget.to_dict(), "estimate": estimate,
            "reused": reused, "observation": observation_text(records), "scenarios": scenario_text(records),
            **summary}


def _run(args: argparse.Namespace, seeds: list[int], arms: list[str], budget: PeersBudget, paths: PeersPaths) -> None:
    print(f"peers: seeds {seeds}, arms {arms}, {budget.online_steps} online env steps per arm", flush=True)
    print(format_estimate(estimate_units(budget, arms, len(seeds), args.workers)), flush=True)
    if args.rerun:
        for record in [paths.record(s, a) for s in seeds for a in arms]:
            record.unlink(missing_ok=True)
    executor = make_executor(args.workers, args.ray_address, serial=args.workers == 1 and args.ray_address is None)
    t0 = time.perf_counter()
    with ray_session(args.ray_address):
        results = run_peers(seeds, arms, budget, paths, executor, snapshot_every=args.snapshot_every)
    print(f"{sum(not r.skipped for r in results)} arm unit(s) run, {sum(r.skipped for r in results)} stored; "
          f"{time.perf_counter() - t0:.0f} s", flush=True)


def _check(args: argparse.Namespace) -> tuple[list[int], list[str], PeersBudget]:
    if args.workers is None:  # --quick: tiny units, where starting a process costs more than the unit
        args.workers = 1 if args.quick else 2
    seeds = select_seeds(args.seeds or ([0, 1] if args.quick else list(range(5))), [])
    arms, budget = check_arms(args.arms), _budget(args)
    check_int("--workers", args.workers)
    check_int("--snapshot-every", args.snapshot_every, low=0)
    check_extras(needed_extras(arms, args.report_only))
    return seeds, arms, budget


def _run_and_report(args: argparse.Namespace, checked: tuple[list[int], list[str], PeersBudget], command: str) -> int:
    seeds, arms, budget = checked
    paths = PeersPaths.under(args.out, args.raw, args.work)
    command, date, recorded = run_header(command, paths.out / "peers.json", args.report_only)
    estimate = None
    if args.report_only:  # the budget and estimate of the run: its manifest, else its report's
        budget = paths.rebuilt_budget(recorded, budget)
        estimate = recorded.get("estimate")
    else:
        _run(args, seeds, arms, budget, paths)
    summary = build_summary(paths, budget, args.workers, command, date, reps=200 if args.quick else 2000,
                            estimate=estimate)
    files = write_report(summary, paths.out)
    for line in verdicts(summary):
        print(line)
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument or a missing extra, 1 when units failed)."""
    return harness_main(build_parser(prog), argv, prog, _check, _run_and_report)
