"""The same small tuning budget for every method of the head-to-head: ``python -m experiments peers-tuning``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common.cli import check_extras, harness_main, select_seeds
from experiments.common.names import SCENARIO_BASES
from experiments.common.records import run_header, table
from experiments.common.runner import make_executor
from experiments.common.stats import run_scores
from experiments.peers.budget import (
    ARM_LABELS,
    FULL_PEERS_BUDGET,
    QUICK_PEERS_BUDGET,
    UA2C_ARMS,
    PeersBudget,
    estimate_units,
)
from experiments.peers.cli import needed_extras
from experiments.peers.runner import PeersPaths, load_records, run_peers
from sb3_ua2c.checks import check_int

PROG = "python -m experiments peers-tuning"


@dataclass(frozen=True)
class Setting:
    """One configuration of one method: its label, hyperparameters and :class:`PeersBudget` keys."""

    label: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    budget: Mapping[str, Any] = field(default_factory=dict)


def _sb3_grid(lr: float) -> tuple[Setting, ...]:
    return (Setting("zoo_configs settings"), Setting(f"learning_rate {lr:g}", {"learning_rate": lr}),
            Setting("learning_starts 100", {"learning_starts": 100}))


#: UA2C's sampler and field on the tuning's day (2026-12-04; the records hold the field): spelt out so that the
#: tuning and its ``selected.json`` stay that day's now that the library's defaults are N = 5 and 256 × 2
TUNING_DAY_FIELD = {"flow_steps": 10, "policy_kwargs": {"net_arch": [512, 512, 512], "n_elite": 8}}  # same as default: n_elite

#: Per tuned method, its configurations; the first is its published setting (the head-to-head's default).
GRID: dict[str, tuple[Setting, ...]] = {
    "ua2c_adaptive": (Setting("λ (q_weight) 1, the default", {**TUNING_DAY_FIELD, "q_weight": 1.0}),  # that day's
                      Setting("λ 0.3", {**TUNING_DAY_FIELD, "q_weight": 0.3}),  # same as default: the value tried
                      Setting("λ 3", {**TUNING_DAY_FIELD, "q_weight": 3.0})),
    "sac": _sb3_grid(1e-3),
    "tqc": _sb3_grid(1e-3),
    "crossq": _sb3_grid(3e-4),
    "rlpd": (Setting("4 updates per env step"), Setting("2 updates per env step", budget={"rlpd_updates_per_step": 2}),
             Setting("8 updates per env step", budget={"rlpd_updates_per_step": 8})),
    "iql": (Setting("expectile 0.7, β 3 (d3rlpy's defaults, IQL's locomotion)"),
            Setting("expectile 0.9, β 10 (IQL's AntMaze)", {"expectile": 0.9, "weight_temp": 10.0}),
            Setting("expectile 0.7, β 0.5 (IQL's Kitchen, Adroit)", {"weight_temp": 0.5})),
    "calql": (Setting("α 5 (d3rlpy's reproduction)"), Setting("α 1 (Cal-QL's Adroit)", {"conservative_weight": 1.0}),
              Setting("α 0.2", {"conservative_weight": 0.2})),
    "rebrac": (Setting("β_actor = β_critic = 0.01 (d3rlpy's reproduction)"),
               Setting("β 0.1 / 0.1", {"actor_beta": 0.1, "critic_beta": 0.1}),
               Setting("β 0.001 / 0.001", {"actor_beta": 0.001, "critic_beta": 0.001})),
}
TUNED_ARMS = tuple(GRID)
N_CONFIGS = 3
#: Validation seeds of the tuning (the test run takes others)
DEFAULT_SEEDS = (0, 1)


def overrides(choice: Mapping[str, int], base: PeersBudget) -> dict[str, Any]:
    """``--budget`` overrides that give each method in ``choice`` its configuration ``choice[arm]`` on ``base``."""
    out: dict[str, Any] = {}
    for arm, index in choice.items():
        if arm not in GRID:
            raise ValueError(f"arms: {arm!r} is not tuned; choose from {list(TUNED_ARMS)}")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(GRID[arm]):
            raise ValueError(f"configuration of {arm!r} must be an integer in [0, {len(GRID[arm])}), got {index!r}")
        setting = GRID[arm][index]
        out.update(setting.budget)
        if setting.kwargs and arm in UA2C_ARMS:
            out["ua2c"] = {"algo_kwargs": {**base.ua2c.algo_kwargs, **setting.kwargs}}
        elif setting.kwargs:
            out.setdefault("peer_kwargs", {})[arm] = dict(setting.kwargs)
    return out


def config_budget(index: int, arms: Sequence[str], base: PeersBudget) -> PeersBudget:
    """The validation budget of configuration ``index``: every method in ``arms`` at its ``index``-th setting."""
    budget = base.with_overrides(overrides({a: index for a in arms}, base))
    return dataclasses.replace(budget, scenarios="validation")


def config_paths(out: str | Path, index: int) -> PeersPaths:
    return PeersPaths.under(Path(out) / f"c{index}")


def collect(out: str | Path, arms: Sequence[str], seeds: Sequence[int]) -> dict[str, Any]:
    """Per method, each configuration's rewards and collision rates per run, and the choice once all ran."""
    methods: dict[str, Any] = {}
    records = [load_records(config_paths(out, i), seeds) for i in range(N_CONFIGS)]
    for arm in arms:
        rows = []
        for i, setting in enumerate(GRID[arm]):
            runs = sorted(records[i].get(arm, []), key=lambda r: r["seed"])
            rows.append({"config": i, "label": setting.label, "seeds": [r["seed"] for r in runs],
                         **{m: run_scores(runs, m).tolist() if runs else [] for m in ("reward", "collision")}})
        complete = all(row["seeds"] == sorted(seeds) for row in rows)
        means = [float(np.mean(row["reward"])) if row["reward"] else None for row in rows]
        chosen = int(np.argmax(means)) if complete else None  # argmax keeps the first of equal means
        methods[arm] = {"configs": rows, "mean_reward": means, "chosen": chosen}
    return methods


def every_method_chosen(methods: Mapping[str, Any]) -> bool:
    """Whether every method has its choice, i.e. ``selected.json`` may feed a test run."""
    return all(m["chosen"] is not None for m in methods.values())


def selected_overrides(methods: Mapping[str, Any], base: PeersBudget) -> dict[str, Any]:
    """The ``--budget`` overrides of the chosen configurations (a method still pending keeps its published one)."""
    return overrides({arm: m["chosen"] for arm, m in methods.items() if m["chosen"] is not None}, base)


def format_markdown(summary: Mapping[str, Any]) -> str:
    lines = [
        "# Tuning of the head-to-head's methods on validation scenarios",
        "",
        f"Command: `{summary['command']}` ({summary['date']}). Validation seeds: {summary['seeds']}; "
        f"validation scenarios (SUMO seeds 1000 · ({SCENARIO_BASES['validation']} + seed) + i), never the test "
        "scenarios. Budget of every run: the head-to-head's "
        f"({summary['online_steps']} online env steps, {summary['eval_episodes']} evaluation episode(s) per run).",
        "",
        f"Every method gets the same budget: {N_CONFIGS} configurations fixed before the runs, the first its published "
        "settings. Chosen: the highest mean final reward over the runs (one score per run: the mean over its "
        "episodes). With this few runs the choice is a rule applied the same way to every method, not a finding: "
        "differences between configurations are mostly within the spread between runs.",
        "",
    ]

    def cells(arm: str, m: Mapping[str, Any], row: Mapping[str, Any], mean: float | None) -> list[str]:
        chosen = "**yes**" if m["chosen"] == row["config"] else ("pending" if m["chosen"] is None else "")
        return [ARM_LABELS[arm], f"{row['config']}: {row['label']}", ", ".join(f"{r:.1f}" for r in row["reward"]) or "—",
                "—" if mean is None else f"{mean:.1f}", ", ".join(f"{c:.2f}" for c in row["collision"]) or "—", chosen]

    lines += table(["method", "configuration", "final reward per run", "mean", "collision rate per run", "chosen"],
                   (cells(arm, m, row, mean) for arm, m in summary["methods"].items()
                    for row, mean in zip(m["configs"], m["mean_reward"], strict=True)))
    if not every_method_chosen(summary["methods"]):
        lines += ["", "Pending: `selected.json`, the test run's `--budget`, is written once every method is chosen.", ""]
    else:
        lines += ["", "`selected.json`, the test run's `--budget`:", "", "```json",
                  json.dumps(summary["selected"], indent=1), "```", ""]
    return "\n".join(lines)


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description="The head-to-head's methods, each in 3 configurations "
                                     "on the validation scenarios; writes the choice for the test run (resumable).")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(DEFAULT_SEEDS), help="validation seeds (default 0 1)")
    parser.add_argument("--arms", nargs="+", default=list(TUNED_ARMS), metavar="ARM",
                        help=f"methods to tune (default: all): {' '.join(TUNED_ARMS)}")
    parser.add_argument("--configs", type=int, nargs="+", default=list(range(N_CONFIGS)),
                        help="configurations to run (default: 0 1 2; the report reads every stored one)")
    parser.add_argument("--quick", action="store_true", help="the head-to-head's --quick budget: a smoke test")
    parser.add_argument("--out", default="results/peers_tuning", help="run directories c<i> and the report")
    parser.add_argument("--workers", type=int, default=2, help="local processes at once (1: in this process)")
    parser.add_argument("--ray-address", default=None, metavar="ADDRESS", help="run the units on a Ray cluster")
    parser.add_argument("--report-only", action="store_true", help="only rebuild the report from the stored records")
    return parser


def _run(args: argparse.Namespace, base: PeersBudget) -> None:
    budgets = {i: config_budget(i, args.arms, base) for i in args.configs}
    walls = [estimate_units(b, args.arms, len(args.seeds), args.workers) for b in budgets.values()]
    print(f"tuning: seeds {args.seeds}, methods {args.arms}, configurations {args.configs}; estimate "
          f"{sum(w['cpu'] for w in walls) / 60:.0f} CPU-min, ~{sum(w['wall'] for w in walls) / 60:.0f} min wall on "
          f"{args.workers} worker(s) (before resuming)", flush=True)
    executor = make_executor(args.workers, args.ray_address, serial=args.workers == 1 and args.ray_address is None)
    for i, budget in budgets.items():
        t0 = time.perf_counter()
        run_peers(args.seeds, args.arms, budget, config_paths(args.out, i), executor)
        print(f"configuration {i}: {time.perf_counter() - t0:.0f} s", flush=True)


def _check(args: argparse.Namespace) -> PeersBudget:
    args.seeds = select_seeds(args.seeds, [])  # the head-to-head's check of --seeds, without repeats
    check_int("--workers", args.workers)
    check_extras(needed_extras(args.arms, args.report_only))
    unknown = [a for a in args.arms if a not in GRID]
    if unknown:
        raise ValueError(f"--arms: {unknown} are not tuned; choose from {list(TUNED_ARMS)}")
    bad = [c for c in args.configs if not 0 <= c < N_CONFIGS]
    if bad:
        raise ValueError(f"--configs must be in [0, {N_CONFIGS}), got {bad}")
    args.arms = [a for a in TUNED_ARMS if a in args.arms]
    return QUICK_PEERS_BUDGET if args.quick else FULL_PEERS_BUDGET


def _run_and_report(args: argparse.Namespace, base: PeersBudget, command: str) -> int:
    out = Path(args.out)
    command, date, _ = run_header(command, out / "tuning.json", args.report_only)
    if not args.report_only:
        _run(args, base)
    methods = collect(out, args.arms, args.seeds)
    summary = {"command": command, "date": date, "seeds": args.seeds, "online_steps": base.online_steps,
               "eval_episodes": base.ua2c.eval_episodes, "methods": methods,
               "selected": selected_overrides(methods, base)}
    out.mkdir(parents=True, exist_ok=True)
    (out / "tuning.json").write_text(json.dumps(summary, indent=1) + "\n")
    (out / "tuning.md").write_text(format_markdown(summary))
    for arm, m in methods.items():
        print(f"{arm}: " + ("pending" if m["chosen"] is None else f"configuration {m['chosen']}, "
                            f"{GRID[arm][m['chosen']].label}"))
    selected = out / "selected.json"
    if not every_method_chosen(methods):  # no test run from a partial choice
        selected.unlink(missing_ok=True)
        print(f"wrote {out / 'tuning.md'}, {out / 'tuning.json'}; {selected.name} waits for every configuration")
        return 0
    selected.write_text(json.dumps(summary["selected"], indent=1) + "\n")
    print(f"wrote {out / 'tuning.md'}, {out / 'tuning.json'}, {selected}")
    return 0


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit code (2 on a bad argument, 1 when units failed)."""
    return harness_main(build_parser(prog), argv, prog, _check, _run_and_report)
