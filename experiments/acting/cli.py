"""Command line of the acting-rule screen: ``python -m experiments acting`` (see ``docs/acting.md``).

Acting rules need no training: the checkpoints a head-to-head run wrote (``python -m experiments peers ...
--snapshot-every 5000``: Phase 1 and the UA2C arm after every 5,000 online steps) are evaluated under every cell,
each run on its own scenarios, the same for every cell. Resumable: one record per (seed, stage, cell)."""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from experiments.acting import report
from experiments.acting.cells import CELLS, STAGES, parse_cell, run_behaviour, run_cell, stage_checkpoint
from experiments.common.cli import check_extras, harness_main, harness_parent, select_seeds
from experiments.common.names import SCENARIO_BASES
from experiments.common.records import recorded_path, run_header
from experiments.common.runner import Unit, make_executor, ray_session, run_units
from sb3_ua2c.checks import check_int

PROG = "python -m experiments acting"
#: CPU seconds of one evaluation episode on one thread (MixedTraffic-v0, up to 200 steps), measured on 2026-12-08:
#: 0.16 with Eq. 7's prefixes, 0.37 with a replanning at every step (replan, ensemble)
EPISODE_SECONDS = 0.25
PARENT = harness_parent(seeds="0 1 2 3 4 5 6 7 8 9 (validation seeds)", work="the --checkpoints run's peers_work",
                        quick="2 episodes per cell: a smoke test", raw="<out>/acting_raw", scenarios=True, rerun=True)


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, parents=[PARENT], description=__doc__.split("\n\n")[1])
    parser.add_argument("--checkpoints", required=True, metavar="RUN",
                        help="the --out of a `python -m experiments peers` run with the arm ua2c (its peers_work holds "
                        "the checkpoints; with --snapshot-every for the online stages)")
    parser.add_argument("--stages", nargs="+", default=list(STAGES), metavar="STAGE",
                        help=f"checkpoints to evaluate: pretrained (Phase 1) or online_<steps> (default: {STAGES})")
    parser.add_argument("--cells", nargs="+", default=list(CELLS), metavar="CELL",
                        help="selection@execution cells (default: every selection with eq7, every execution with "
                        "elite, uncertainty and mean)")
    parser.add_argument("--episodes", type=int, default=100, help="evaluation episodes per run and cell (default 100)")
    return parser


def _check(args: argparse.Namespace) -> dict[str, Any]:
    seeds = select_seeds(args.seeds, list(range(10)))
    for cell in args.cells:
        parse_cell(cell)
    check_int("--episodes", args.episodes)
    check_int("--workers", args.workers)
    check_extras(["rliable"])
    work = Path(args.work) if args.work else Path(args.checkpoints) / "peers_work"
    if not args.report_only and not work.is_dir():
        raise ValueError(f"--checkpoints: {work} does not exist (run `python -m experiments peers --out "
                         f"{args.checkpoints} --arms ua2c --snapshot-every 5000 ...` first)")
    return {"seeds": seeds, "work": work, "episodes": 2 if args.quick else args.episodes,
            "cells": list(dict.fromkeys(args.cells)), "stages": list(dict.fromkeys(args.stages))}


def units(checked: dict[str, Any], scenarios: str, raw: Path) -> list[Unit]:
    """The behaviour policy of every seed, then every (stage, cell, seed) in the order given: a run stopped early
    leaves whole cells (every seed) of the first stages and cells."""
    out, episodes = [], checked["episodes"]
    for seed in checked["seeds"]:
        seed_work = checked["work"] / f"seed{seed}"
        dataset, scenario = str(seed_work / "dataset"), SCENARIO_BASES[scenarios] + seed
        out.append(Unit(f"seed{seed}/behaviour", run_behaviour,
                        {"seed": seed, "dataset": dataset, "scenario_seed": scenario, "episodes": episodes},
                        raw / f"seed{seed}" / "behaviour.json"))
    for stage in checked["stages"]:
        checkpoints = {seed: recorded_path(stage_checkpoint(checked["work"] / f"seed{seed}", stage))
                       for seed in checked["seeds"]}
        for cell in checked["cells"]:
            for seed in checked["seeds"]:
                out.append(Unit(f"seed{seed}/{stage}/{cell}", run_cell,
                                {"seed": seed, "stage": stage, "cell": cell, "checkpoint": checkpoints[seed],
                                 "dataset": str(checked["work"] / f"seed{seed}" / "dataset"), "episodes": episodes,
                                 "scenario_seed": SCENARIO_BASES[scenarios] + seed},
                                raw / f"seed{seed}" / stage / f"{cell}.json"))
    return out


def _run(args: argparse.Namespace, checked: dict[str, Any], command: str) -> int:
    out = Path(args.out)
    raw = Path(args.raw) if args.raw else out / "acting_raw"
    command, date, _ = run_header(command, out / "acting.json", args.report_only)
    if not args.report_only:
        todo = units(checked, args.scenarios, raw)
        if args.rerun:
            for unit in todo:
                unit.result_file.unlink(missing_ok=True)
        stored = sum(u.result_file.is_file() for u in todo)
        cpu = (len(todo) - stored) * checked["episodes"] * EPISODE_SECONDS
        print(f"acting: {len(todo)} units ({stored} stored), {checked['episodes']} episodes each: about "
              f"{cpu / 60:.0f} CPU-min, ~{cpu / 60 / args.workers:.0f} min wall on {args.workers} worker(s)", flush=True)
        executor = make_executor(args.workers, args.ray_address, serial=args.workers == 1 and args.ray_address is None)
        t0 = time.perf_counter()
        with ray_session(args.ray_address):
            run_units(todo, executor)
        print(f"{time.perf_counter() - t0:.0f} s", flush=True)
    summary = report.aggregate(report.load_records(raw), reps=200 if args.quick else 2000)
    summary.update(command=command, date=date, episodes=checked["episodes"], scenarios=f"{args.scenarios} scenarios",
                   checkpoints=f"{recorded_path(checked['work'])}, stages {checked['stages']}")
    files = report.write(summary, out, checked["cells"])
    for stage, s in summary["stages"].items():
        print(f"{stage}: best cell {s['best']} ({s['cells'][s['best']]['reward']['mean']:.1f})")
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument or a missing extra, 1 when units failed)."""
    return harness_main(build_parser(prog), argv, prog, _check, _run)
