"""Command line of the execution-rule study: ``python -m experiments.execution``.

Examples::

    python -m experiments.execution --role development --seeds 0 1 2 --workers 2     # the screen (validation)
    python -m experiments.execution --role confirmation --seeds 10 11 12 13 14 --online fixed growth0.5
    python -m experiments.execution --quick --out /tmp/exe                             # end to end in seconds
    python -m experiments.execution --role development --report-only                  # rebuild the report

A development run evaluates on validation scenarios (seed base 3,000) and is where rules are chosen; a
confirmation run evaluates on test scenarios (seed base 4,000) with seeds never used for a choice.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from experiments.common.names import SCENARIO_BASES
from experiments.execution.controls import RULES

PROG = "python -m experiments.execution"
#: the scenarios of each role (:data:`~experiments.common.names.SCENARIO_BASES`)
ROLES = {"development": "validation", "confirmation": "test"}
#: one evaluation episode (20 s of traffic, one replanning per step at worst) and one run's training, in
#: CPU seconds on one thread of these 2-core machines (make main: 10 s data, 55 s Phase 1, 47 s Phase 2)
EPISODE_SECONDS = 0.6
TRAINING_SECONDS = {"data_and_phase1": 70.0, "phase2": 55.0}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="Execution rules against fixed chunks and matched-length "
                                     "controls on MixedTraffic-v0 (make main's pipeline, one run per seed).")
    parser.add_argument("--role", choices=sorted(ROLES), default="development",
                        help="development: validation scenarios; confirmation: test scenarios (default: development)")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="run seeds (default: 0 1 2; --quick: 0 1)")
    parser.add_argument("--online", nargs="+", default=["fixed", "delta0"],
                        help=f"rules of the Phase-2 checkpoints among {list(RULES)} (default: fixed delta0)")
    parser.add_argument("--rules", nargs="+", default=list(RULES),
                        help="rules the pre-trained checkpoint (and, without --own-rule-only, every checkpoint) is "
                             "evaluated with")
    parser.add_argument("--own-rule-only", action="store_true",
                        help="evaluate each fine-tuned checkpoint with fixed chunks and its own rule only")
    parser.add_argument("--episodes", type=int, default=None,
                        help="evaluation episodes per checkpoint, arm and mode (default: 20; --quick: 1)")
    parser.add_argument("--out", default="results", help="report directory (execution_<role>.md / .json)")
    parser.add_argument("--work", default=None, help="datasets, checkpoints, unit records (default: <out>/execution_work)")
    parser.add_argument("--workers", type=int, default=2, help="local processes at once (default: 2)")
    parser.add_argument("--ray-address", default=None, help="run the seeds on this Ray cluster")
    parser.add_argument("--quick", action="store_true", help="a tiny budget: a smoke test")
    parser.add_argument("--report-only", action="store_true", help="rebuild the report from the stored runs")
    return parser


def _check(args: argparse.Namespace) -> None:
    unknown = sorted((set(args.online) | set(args.rules)) - set(RULES))
    if unknown:
        raise ValueError(f"unknown rules {unknown}; known: {list(RULES)}")
    if "fixed" not in args.rules:
        raise ValueError("--rules must include 'fixed' (the reference every rule is paired with)")


def estimate_minutes(n_seeds: int, n_online: int, n_rules: int, episodes: int, workers: int,
                     own_rule_only: bool = False) -> float:
    """Wall minutes on ``workers`` cores: training plus the evaluations (a rule other than ``fixed`` comes with
    its two controls) of ``(1 + n_online)`` checkpoints × rules × 2 modes × episodes (with ``own_rule_only``,
    a fine-tuned checkpoint has at most 4 arms: fixed, its rule and the rule's controls)."""
    per_seed = TRAINING_SECONDS["data_and_phase1"] + n_online * TRAINING_SECONDS["phase2"]
    arms = (3 * n_rules - 2) + n_online * (4 if own_rule_only else 3 * n_rules - 2)
    per_seed += arms * 2 * episodes * EPISODE_SECONDS
    return per_seed * n_seeds / 60.0 / max(1, min(workers, n_seeds))


def main(argv: Sequence[str] | None = None) -> int:
    from experiments.common.records import command_line, run_header
    from experiments.common.runner import Unit, make_executor, run_units
    from experiments.execution import report, unit
    from sb3_ua2c.checks import check_int

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        _check(args)
    except ValueError as exc:
        parser.error(str(exc))
    seeds = args.seeds or ([0, 1] if args.quick else [0, 1, 2])
    budget = dict(unit.BUDGETS["quick" if args.quick else "full"])
    if args.episodes is not None:
        check_int("--episodes", args.episodes)
        budget["eval_episodes"] = args.episodes
    out = Path(args.out)
    work = Path(args.work) if args.work else out / "execution_work"
    name = f"execution_{args.role}"
    base = SCENARIO_BASES[ROLES[args.role]]
    units = [Unit(f"seed{s}", unit.run_seed,
                  dict(seed=s, work=str(work / args.role), budget=budget, online_rules=args.online,
                       screened_rules=args.rules, scenario_base=base, own_rule_only=args.own_rule_only),
                  result_file=work / args.role / f"seed{s}.json") for s in seeds]
    if args.report_only:
        missing = [u.name for u in units if not u.result_file.is_file()]
        if missing:
            print(f"error: no stored runs for {missing} under {work / args.role}", file=sys.stderr)
            return 2
    else:
        todo = sum(not u.result_file.is_file() for u in units)  # stored runs are not run again
        minutes = estimate_minutes(todo, len(args.online), len(args.rules), budget["eval_episodes"],
                                   args.workers, args.own_rule_only) if todo else 0.0
        print(f"{PROG}: {args.role}, seeds {seeds}, online {args.online}, {len(args.rules)} rules; "
              f"estimate {minutes:.0f} min wall on {args.workers} worker(s)", flush=True)
        run_units(units, make_executor(args.workers, args.ray_address, serial=args.quick and args.workers == 1))
    records = [json.loads(u.result_file.read_text()) for u in units]
    command, date = run_header(command_line(PROG, argv), out / f"{name}.json" if args.report_only else None)
    summary = report.summarize(records)
    online = report.online_protocol(records)
    header = [f"Command: `{command}`", f"Date: {date}", f"Role: {args.role} (scenario seed base {base}); seeds {seeds}",
              f"Budget per run: {records[0]['budget']}"]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps({"command": command, "date": date, "role": args.role,
                                                  "seeds": seeds, "budget": records[0]["budget"], "summary": summary,
                                                  "online_protocol": online}, indent=1))
    (out / f"{name}.md").write_text(report.markdown(summary, header, report.threshold_quantiles(records), online))
    print(f"wrote {out / name}.md")
    return 0
