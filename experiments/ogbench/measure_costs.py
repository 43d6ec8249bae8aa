"""Cost of one OGBench unit per arm at a small budget, and the full table's cost extrapolated from it.

Usage::

    python -m experiments.ogbench.measure_costs --data-dir DIR [--dataset-episodes 100] [--pretrain-steps 2000]
        [--finetune-steps 2000] [--eval-episodes 10] [--target-pretrain 20000]
        [--target-finetune 20000] [--target-eval 50] [--seeds 5] [--tasks 1] [--cores 2]

Runs :func:`experiments.ogbench.unit.run_ogbench_unit` once per arm on one thread (the dataset is
generated in ``DIR`` first when missing, and its generation timed), prints each phase's CPU
seconds, then fits a linear cost per arm (CPU seconds per pre-training update, per online
environment step with its updates, per evaluation episode) and extrapolates the table of
``arms × seeds × tasks`` units at the target budget on ``cores`` cores. Evaluation episodes are
costed at their measured mean length: with no success every episode runs its full 200 steps, the
upper bound.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

from experiments.ogbench.runner import DEFAULT_TASK
from experiments.ogbench.unit import ARMS, OGBenchBudget, ensure_dataset, run_ogbench_unit


def unit_rates(record: dict) -> dict[str, float]:
    """CPU seconds per update, per online step and per evaluation episode of one unit's record."""
    s, b = record["seconds"], record["budget"]
    episodes = 2 * b["eval_episodes"] + b["curve_points"] * b["curve_episodes"]
    return {
        "per_update": s["pretrain_cpu"] / b["pretrain_steps"],
        "per_online_step": s["finetune_cpu"] / b["finetune_steps"],
        "per_eval_episode": (s["eval_offline_cpu"] + s["eval_online_cpu"]) / (2 * b["eval_episodes"]),
        "fixed": s["data_cpu"],
        "eval_episodes_measured": episodes,
    }


def unit_estimate(rates: dict[str, float], pretrain: int, finetune: int, eval_episodes: int, curve: int) -> float:
    """CPU seconds of one unit at the target budget (``curve`` = further evaluation episodes in Phase 2)."""
    return (rates["fixed"] + pretrain * rates["per_update"] + finetune * rates["per_online_step"]
            + (2 * eval_episodes + curve) * rates["per_eval_episode"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default=DEFAULT_TASK, help=f"OGBench single-task name (default: {DEFAULT_TASK})")
    parser.add_argument("--data-dir", required=True)
    parser.add_argument("--out", default=None, help="unit directories (default: <data-dir>/units)")
    parser.add_argument("--dataset-episodes", type=int, default=100)
    parser.add_argument("--pretrain-steps", type=int, default=2000)
    parser.add_argument("--finetune-steps", type=int, default=2000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target-pretrain", type=int, default=20_000)
    parser.add_argument("--target-finetune", type=int, default=20_000)
    parser.add_argument("--target-eval", type=int, default=50)
    parser.add_argument("--target-curve", type=int, default=40, help="Phase-2 evaluation episodes per unit")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--tasks", type=int, default=1)
    parser.add_argument("--cores", type=int, default=2)
    args = parser.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)

    budget = OGBenchBudget(dataset_episodes=args.dataset_episodes, pretrain_steps=args.pretrain_steps,
                           finetune_steps=args.finetune_steps, eval_episodes=args.eval_episodes, curve_points=0)
    cpu = time.process_time()
    path, generation = ensure_dataset(args.task, budget, args.data_dir)
    if generation is not None:
        print(f"generated {path}: {json.dumps(generation)}")
    print(f"dataset ready after {time.process_time() - cpu:.1f} CPU s")
    out = args.out or f"{args.data_dir}/units"
    total = 0.0
    for arm in args.arms:
        record = run_ogbench_unit(arm, args.task, args.seed, budget, f"{out}/{arm}-s{args.seed}", data_dir=args.data_dir)
        rates = unit_rates(record)
        estimate = unit_estimate(rates, args.target_pretrain, args.target_finetune, args.target_eval, args.target_curve)
        total += estimate * args.seeds * args.tasks
        seconds = {k: round(v, 1) for k, v in record["seconds"].items() if k.endswith("_cpu")}
        mean_length = sum(record["eval_online"]["lengths"]) / len(record["eval_online"]["lengths"])
        print(f"{arm:>8}: success offline {record['success_offline']:.2f} online {record['success_online']:.2f}, "
              f"CPU s {seconds}, {1000 * rates['per_update']:.1f} ms/update, "
              f"{1000 * rates['per_online_step']:.2f} ms/online step, {rates['per_eval_episode']:.2f} s/eval episode "
              f"(mean length {mean_length:.0f}) -> {estimate / 60:.1f} CPU min per unit at the target budget")
    print(f"table: {len(args.arms)} arms x {args.seeds} seeds x {args.tasks} task(s) at {args.target_pretrain} updates + "
          f"{args.target_finetune} online steps + 2 x {args.target_eval} (+{args.target_curve}) eval episodes: "
          f"{total / 3600:.2f} CPU h = {total / 3600 / args.cores:.2f} h wall on {args.cores} cores (datasets apart)")


if __name__ == "__main__":
    main()
