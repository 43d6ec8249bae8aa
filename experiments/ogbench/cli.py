"""Command line of the OGBench benchmark: ``python -m experiments ogbench`` (see ``docs/ogbench.md``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import warnings
from collections.abc import Sequence
from pathlib import Path

from experiments.common.cli import check_extras, harness_main, harness_parent
from experiments.common.records import run_header
from experiments.common.runner import make_executor
from experiments.ogbench import report, runner
from experiments.ogbench.runner import DEFAULT_TASK
from experiments.ogbench.unit import ARMS
from sb3_ua2c.checks import check_int

PROG = "python -m experiments ogbench"
PARENT = harness_parent(seeds="0 1 2 3 4; 0 1 with --quick", work="<out>/ogbench_work", workers=1,
                        workers_help="local processes at once (default: 1)",
                        quick="a tiny budget and 2 seeds, end to end in seconds (CI)")


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, parents=[PARENT], description="OGBench single-task benchmark: offline pre-training on locally "
        "generated data, then online fine-tuning, per arm and seed; success rates with rliable statistics. Resumable.")
    parser.add_argument("--task", default=DEFAULT_TASK, help=f"OGBench single-task name (default: {DEFAULT_TASK})")
    parser.add_argument("--episodes", type=int, default=None,
                        help="evaluation episodes per checkpoint (default: the task's budget, 50; episode i of "
                             "seed s resets with seed 10,000,000 + 1000 s + i, the test scenarios)")
    parser.add_argument("--arms", nargs="+", default=list(ARMS), help=f"arms among {list(ARMS)} (default: all)")
    parser.add_argument("--serial", action="store_true",
                        help="run the units one after the other in this process, whatever --workers says (the default with "
                             "--quick and one worker; not with --ray-address)")
    return parser


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument or a missing extra, 1 when units failed)."""
    return harness_main(build_parser(prog), argv, prog, lambda args: None, _run)  # checked in _run: exit code 2


def _run(args: argparse.Namespace, _: None, command: str) -> int:
    runner.check_task(args.task)
    arms = runner.check_arms(args.arms)
    seeds = runner.seeds_arg(args.seeds if args.seeds is not None else range(2 if args.quick else 5))
    check_int("--workers", args.workers)
    if args.serial and args.ray_address is not None:
        raise ValueError("--serial runs the units in this process: it cannot be combined with --ray-address")
    check_extras(["ogbench", "rliable"])  # the environments, the report's statistics
    budget = runner.default_budget(args.task, quick=args.quick)
    if args.episodes is not None:
        check_int("--episodes", args.episodes)
        if args.episodes > 1000:  # episode i of seed s resets with base + 1000 s + i
            raise ValueError(f"--episodes must be <= 1000 (more would replay the next seed's scenarios), "
                             f"got {args.episodes}")
        budget = dataclasses.replace(budget, eval_episodes=args.episodes)
    out = Path(args.out)
    work = Path(args.work) if args.work else out / "ogbench_work"
    est = runner.estimate(arms, len(seeds), budget, args.workers)
    print(runner.format_estimate(args.task, arms, seeds, budget, args.workers, est), flush=True)
    plots = True
    if args.report_only:
        try:
            records = runner.stored_records(args.task, arms, seeds, work)
        except ValueError:
            if not (out / "ogbench.json").is_file():
                raise
            # a checkout keeps the report, not the units: rebuild the statistics from its run records
            recorded = json.loads((out / "ogbench.json").read_text())
            records, plots, est = report.records_from_report(recorded), False, recorded.get("estimate") or est
    else:
        # a fresh process per unit costs seconds of imports: the quick run stays in this one
        serial = args.serial or (args.quick and args.workers == 1 and args.ray_address is None)
        executor = make_executor(args.workers, args.ray_address, serial=serial)
        with warnings.catch_warnings():  # OGBench's float32 Box bounds warn once per environment
            warnings.simplefilter("ignore", UserWarning)
            records = runner.run_benchmark(args.task, arms, seeds, budget, work, executor)
    # the quick run's statistics mean nothing: fewer bootstrap replications keep it fast
    command, date, _ = run_header(command, out / "ogbench.json", args.report_only)
    summary = report.write_report(records, out, command=command, estimate=est, reps=200 if args.quick else 2000,
                                  date=date, plots=plots)
    for arm, s in summary["arms"].items():
        print(f"{arm:>9}: success offline {100 * s['offline']['mean']:.1f} %, online {100 * s['online']['mean']:.1f} %")
    print(f"ranking (fixed vs one-step, online): {summary['ranking']['ours_online']}; Q-chunking: "
          f"{summary['ranking']['qc']}")
    print(f"report: {out / 'ogbench.md'}, {out / 'ogbench.json'}")
    return 0
