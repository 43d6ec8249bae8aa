"""Cost of one unit of every peer arm of the head-to-head, and the full table it implies.

Usage::

    python -m experiments.peers.measure_costs --work DIR [--arms sac iql ...] [--online-steps 2000]
        [--offline-steps 500] [--dataset-episodes 200] [--eval-episodes 20] [--full-online-steps 10000]
        [--full-offline-steps 6000] [--seeds 5] [--workers 2]

Collects seed 0's Figure-2-sized dataset, runs one unit of each peer arm (:data:`MEASURED_ARMS`, the arms of
:mod:`experiments.peers.budget` that :class:`~experiments.peers.budget.PeerCostModel` prices) at a small
budget, each in a fresh process, through the head-to-head's own units (:func:`experiments.peers.runner.arm_unit`
on Figure 2's evaluation scenarios), and prints per unit the wall and CPU seconds of each phase. From the CPU
seconds per online step, per offline gradient step and per evaluation episode it extrapolates a unit
at the full budget and the peers' share of the full table (``--seeds`` seeds on ``--workers``
cores). CPU seconds are used because they do not grow when other processes share the cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from experiments.common.runner import ProcessExecutor, run_units
from experiments.peers.budget import ARMS, FULL_PEERS_BUDGET, UA2C_ARMS, PeersBudget

#: The arms priced by :class:`~experiments.peers.budget.PeerCostModel`: every arm but UA2C's (Figure 2's
#: cost model) and the behaviour policy (nothing trained)
MEASURED_ARMS = tuple(a for a in ARMS if a not in UA2C_ARMS and a != "behaviour")


def measured_budget(online: int, offline: int, dataset_episodes: int, eval_episodes: int) -> PeersBudget:
    """The head-to-head's default budget cut to the measured units' size, on Figure 2's evaluation scenarios."""
    ua2c = {"dataset_episodes": dataset_episodes, "pretrain_steps": offline, "eval_episodes": eval_episodes}
    return FULL_PEERS_BUDGET.with_overrides({"ua2c": ua2c, "scenarios": "figure2"}).with_online_steps(online)


def online_updates(record: dict, online: int) -> int:
    """Gradient steps of an online phase of ``online`` env steps: one per step after SB3's
    ``learning_starts`` random steps (d3rlpy updates from the first step)."""
    return max(online - int(record["hyperparams"].get("learning_starts", 0)), 1)


def full_unit_seconds(record: dict, online: int, offline: int, eval_episodes: int) -> float:
    """CPU seconds of ``record``'s unit scaled to ``online`` env steps, ``offline`` gradient steps and
    ``eval_episodes`` evaluation episodes per evaluation: the online phase by its gradient steps
    (:func:`online_updates`; the env steps cost little next to them), the others linearly."""
    cpu = record["cpu_seconds"]
    per_eval = record["eval_episodes"] * len(record["eval_seeds"])
    total = cpu.get("online", 0.0) * online_updates(record, online) / online_updates(record, record["online_steps"])
    if record["offline_steps"]:
        total += cpu.get("offline", 0.0) * offline / record["offline_steps"]
    for phase in ("evaluate", "evaluate_offline"):
        total += cpu.get(phase, 0.0) * eval_episodes / per_eval
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True, help="directory of the dataset and the units")
    parser.add_argument("--arms", nargs="+", choices=MEASURED_ARMS, default=list(MEASURED_ARMS))
    parser.add_argument("--online-steps", type=int, default=2000)
    parser.add_argument("--offline-steps", type=int, default=500)
    parser.add_argument("--dataset-episodes", type=int, default=200)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--full-online-steps", type=int, default=10000)
    parser.add_argument("--full-offline-steps", type=int, default=6000)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    from experiments.peers.runner import PeersPaths, arm_unit, dataset_units

    budget = measured_budget(args.online_steps, args.offline_steps, args.dataset_episodes, args.eval_episodes)
    paths = PeersPaths.under(args.work)
    paths.seed_work(0).mkdir(parents=True, exist_ok=True)
    run_units(dataset_units([0], budget, paths), ProcessExecutor(1))
    units = [arm_unit(arm, 0, budget, paths, {}) for arm in args.arms]
    records = {arm: r.value for arm, r in zip(args.arms, run_units(units, ProcessExecutor(1)), strict=True)}
    print(f"\nper unit at {args.online_steps} online steps, {args.offline_steps} offline steps, "
          f"{args.eval_episodes} evaluation episodes (wall s / CPU s per phase):")
    full = {}
    for arm in args.arms:
        rec = records[arm]
        phases = ", ".join(f"{k} {rec['wall_seconds'][k]:.1f}/{rec['cpu_seconds'][k]:.1f}"
                           for k in rec["cpu_seconds"] if k != "total")
        full[arm] = full_unit_seconds(rec, args.full_online_steps, args.full_offline_steps, args.eval_episodes)
        print(f"  {arm:16s} total {rec['wall_seconds']['total']:7.1f} / {rec['cpu_seconds']['total']:7.1f}  ({phases})"
              f"  reward {rec['evaluation']['summary']['reward']:.2f}")
    print(f"\nestimate at {args.full_online_steps} online steps and {args.full_offline_steps} offline steps "
          f"(CPU seconds per unit, one core each):")
    for arm in args.arms:
        print(f"  {arm:16s} {full[arm]:8.0f} s")
    table = sum(full.values()) * args.seeds / args.workers
    print(f"peer arms x {args.seeds} seeds on {args.workers} cores: {table / 60:.0f} min wall "
          "(plus the UA2C arms, estimated by fig2)")


if __name__ == "__main__":
    main()
