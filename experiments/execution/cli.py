"""Command line of the execution-rule study: ``python -m experiments execution``; a development run chooses on
validation scenarios, a confirmation run evaluates on test scenarios with seeds never used for a choice."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from experiments.common.cli import check_extras, harness_main, harness_parent, select_seeds
from experiments.common.names import SCENARIO_BASES
from experiments.common.records import run_header
from experiments.common.runner import Unit, make_executor, run_units
from experiments.execution import report, unit
from experiments.execution.controls import RULES
from experiments.ogbench.runner import DEFAULT_TASK
from experiments.ogbench.unit import EVAL_SEED_BASE, VALIDATION_SEED_BASE
from sb3_ua2c.checks import check_int

PROG = "python -m experiments execution"
#: the scenarios of each role (:data:`~experiments.common.names.SCENARIO_BASES`)
ROLES = {"development": "validation", "confirmation": "test"}
#: per task: one evaluation episode (MixedTraffic-v0: 20 s of traffic, one replanning per step at worst; OGBench
#: pointmaze: a failed 1,000-step episode) and one run's training, in CPU seconds on one thread of these 2-core
#: machines (make main: 10 s data, 55 s Phase 1, 47 s Phase 2; the OGBench report's units: 560 s and 200 s)
EPISODE_SECONDS = {"traffic": 0.6, "ogbench": 2.5}
TRAINING_SECONDS = {"traffic": {"data_and_phase1": 70.0, "phase2": 55.0},
                    "ogbench": {"data_and_phase1": 560.0, "phase2": 200.0}}
ENVS = ("traffic", "ogbench")


PARENT = harness_parent(seeds="0 1 2; --quick: 0 1", work="<out>/execution_work")


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, parents=[PARENT], description="Execution rules against fixed chunks "
                                     "and matched-length controls on MixedTraffic-v0 (make main's pipeline) or an "
                                     "OGBench task (the OGBench harness's budget), one run per seed.")
    parser.add_argument("--env", choices=ENVS, default="traffic",
                        help="traffic: MixedTraffic-v0 (default); ogbench: the OGBench task of --task")
    parser.add_argument("--task", default=None,
                        help="OGBench task with --env ogbench (default: the OGBench harness's, "
                             "pointmaze-medium-navigate-singletask-task1-v0)")
    parser.add_argument("--role", choices=sorted(ROLES), default="development",
                        help="development: validation scenarios; confirmation: test scenarios (default: development)")
    parser.add_argument("--online", nargs="+", default=["fixed", "delta0"],
                        help=f"rules of the Phase-2 checkpoints among {list(RULES)} (default: fixed delta0)")
    parser.add_argument("--rules", nargs="+", default=list(RULES),
                        help="rules the pre-trained checkpoint (and, without --own-rule-only, every checkpoint) is "
                             "evaluated with")
    parser.add_argument("--own-rule-only", action="store_true",
                        help="evaluate each fine-tuned checkpoint with fixed chunks and its own rule only")
    parser.add_argument("--episodes", type=int, default=None,
                        help="evaluation episodes per checkpoint, arm and mode (default: 20; --quick: 1)")
    return parser


def _check(args: argparse.Namespace) -> tuple[list[int], dict[str, Any]]:
    unknown = sorted((set(args.online) | set(args.rules)) - set(RULES))
    if unknown:
        raise ValueError(f"unknown rules {unknown}; known: {list(RULES)}")
    if "fixed" not in args.rules:
        raise ValueError("--rules must include 'fixed' (the reference every rule is paired with)")
    check_int("--workers", args.workers)
    if not args.report_only and args.env == "ogbench":
        check_extras(["ogbench"])
    seeds = select_seeds(args.seeds, [0, 1] if args.quick else [0, 1, 2])
    setup = _setup(args)
    if args.episodes is not None:
        check_int("--episodes", args.episodes)
        setup["budget"]["eval_episodes"] = args.episodes
    return seeds, setup


def estimate_minutes(n_seeds: int, n_online: int, n_rules: int, episodes: int, workers: int,
                     own_rule_only: bool = False, env: str = "traffic") -> float:
    """Wall minutes on ``workers`` cores: training, and evaluations of every checkpoint, rule, control and mode."""
    training = TRAINING_SECONDS[env]
    per_seed = training["data_and_phase1"] + n_online * training["phase2"]
    arms = (3 * n_rules - 2) + n_online * (4 if own_rule_only else 3 * n_rules - 2)
    per_seed += arms * 2 * episodes * EPISODE_SECONDS[env]
    return per_seed * n_seeds / 60.0 / max(1, min(workers, n_seeds))


def _setup(args: argparse.Namespace) -> dict[str, Any]:
    """What differs between the tasks: the run function, its budget, scenarios, score, report and work names."""
    role = args.role
    if args.env == "traffic":
        if args.task is not None:
            raise ValueError("--task is for --env ogbench")
        return {"run_seed": unit.run_traffic_study, "budget": dict(unit.BUDGETS["quick" if args.quick else "full"]),
                "scenario_base": SCENARIO_BASES[ROLES[role]], "extra": {}, "task": "MixedTraffic-v0",
                "metric": "reward", "digits": 1, "name": f"execution_{role}", "work": role, "secondary": None}
    task = args.task or DEFAULT_TASK
    return {"run_seed": unit.run_ogbench_study, "budget": unit.study_budget(task, args.quick).to_dict(),
            "scenario_base": VALIDATION_SEED_BASE if role == "development" else EVAL_SEED_BASE,
            "extra": {"task": task}, "task": task, "metric": "success", "digits": 2,
            "name": f"execution_ogbench_{role}", "work": f"ogbench_{role}",
            "secondary": ("return", "−1 per step until the goal, so a failed episode scores −1000; it separates rules "
                          "that all reach the goal")}


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument, a missing extra or runs, 1 when runs failed)."""
    return harness_main(build_parser(prog), argv, prog, _check,
                        lambda args, checked, command: _run(args, command, *checked, prog))


def _run(args: argparse.Namespace, command: str, seeds: list[int], setup: dict[str, Any], prog: str) -> int:
    """Run (or, with ``--report-only``, load) one unit per seed, then write ``<name>.md`` and ``<name>.json``."""
    out = Path(args.out)
    work = (Path(args.work) if args.work else out / "execution_work") / setup["work"]
    units = [Unit(f"seed{s}", setup["run_seed"],
                  dict(seed=s, work=str(work), budget=setup["budget"], online_rules=args.online,
                       screened_rules=args.rules, scenario_base=setup["scenario_base"],
                       own_rule_only=args.own_rule_only, **setup["extra"]),
                  result_file=work / f"seed{s}.json") for s in seeds]
    if args.report_only:
        missing = [u.name for u in units if not u.result_file.is_file()]
        if missing:
            raise ValueError(f"no stored runs for {missing} under {work}")
    else:
        todo = sum(not u.result_file.is_file() for u in units)  # stored runs are not run again
        minutes = estimate_minutes(todo, len(args.online), len(args.rules), setup["budget"]["eval_episodes"],
                                   args.workers, args.own_rule_only, args.env) if todo else 0.0
        print(f"{prog}: {args.role}, seeds {seeds}, online {args.online}, {len(args.rules)} rules; "
              f"estimate {minutes:.0f} min wall on {args.workers} worker(s)", flush=True)
        run_units(units, make_executor(args.workers, args.ray_address, serial=args.quick and args.workers == 1))
    records = [json.loads(u.result_file.read_text()) for u in units]
    name, metric = setup["name"], setup["metric"]
    command, date, _ = run_header(command, out / f"{name}.json", args.report_only)
    summary = report.summarize(records, metric)
    online = report.online_protocol(records, metric)
    header = [f"Command: `{command}`", f"Date: {date}",
              f"Role: {args.role} (scenario seed base {setup['scenario_base']}); seeds {seeds}",
              f"Budget per run: {records[0]['budget']}"]
    second: dict[str, Any] = {}
    second_lines: list[str] = []
    if setup["secondary"]:
        second_metric, meaning = setup["secondary"]
        second = {"metric": second_metric, "summary": report.summarize(records, second_metric),
                  "online_protocol": report.online_protocol(records, second_metric)}
        second_lines = report.secondary_lines(second_metric, meaning, second["summary"], second["online_protocol"])
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps({"command": command, "date": date, "role": args.role,
                                                  "seeds": seeds, "budget": records[0]["budget"], "summary": summary,
                                                  "online_protocol": online, "second_score": second}, indent=1))
    (out / f"{name}.md").write_text(report.markdown(summary, header, report.threshold_quantiles(records), online,
                                                    task=setup["task"], metric=metric, digits=setup["digits"],
                                                    secondary=second_lines))
    print(f"wrote {out / name}.md")
    return 0
