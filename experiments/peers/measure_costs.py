"""Cost of one unit of every peer arm of the head-to-head, and the full table it implies.

Usage::

    python -m experiments.peers.measure_costs --work DIR [--online-steps 2000] [--offline-steps 500]
        [--dataset-episodes 200] [--eval-episodes 20] [--full-online-steps 10000]
        [--full-offline-steps 6000] [--seeds 5] [--workers 2]

Collects one Figure-2-sized dataset (seed 0, like ``fig2``'s), runs one unit of each peer arm
(SAC, TQC, SAC + offline data, IQL, Cal-QL) at a small budget, each in a fresh process through
:mod:`experiments.common.runner`, and prints per unit the wall and CPU seconds of each phase. From the CPU
seconds per online step, per offline gradient step and per evaluation episode it extrapolates a unit
at the full budget and the peers' share of the full table (``--seeds`` seeds on ``--workers``
cores). CPU seconds are used because they do not grow when other processes share the cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from experiments.common.runner import ProcessExecutor, Unit, run_units

ARMS = ("sac", "tqc", "sac_offline_mix", "iql", "calql")


def peer_units(work: Path, dataset: Path, online: int, offline: int, eval_episodes: int) -> list[Unit]:
    from experiments.peers import run_d3rlpy, run_sb3_offline_mix, run_sb3_online

    common = {"dataset": str(dataset), "seed": 0, "online_steps": online, "eval_seeds": (2000,),
              "eval_episodes": eval_episodes}
    return [
        Unit("sac", run_sb3_online, {**common, "out_dir": str(work / "sac"), "algo": "sac"}, work / "sac.json"),
        Unit("tqc", run_sb3_online, {**common, "out_dir": str(work / "tqc"), "algo": "tqc"}, work / "tqc.json"),
        Unit("sac_offline_mix", run_sb3_offline_mix, {**common, "out_dir": str(work / "mix")}, work / "mix.json"),
        Unit("iql", run_d3rlpy, {**common, "out_dir": str(work / "iql"), "algo": "iql", "offline_steps": offline},
             work / "iql.json"),
        Unit("calql", run_d3rlpy, {**common, "out_dir": str(work / "calql"), "algo": "calql",
                                   "offline_steps": offline}, work / "calql.json"),
    ]


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
    parser.add_argument("--online-steps", type=int, default=2000)
    parser.add_argument("--offline-steps", type=int, default=500)
    parser.add_argument("--dataset-episodes", type=int, default=200)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--full-online-steps", type=int, default=10000)
    parser.add_argument("--full-offline-steps", type=int, default=6000)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    from envs.collection import collect_dataset
    from sb3_ua2c.offline import load_dataset

    dataset = args.work / "dataset"
    if not (dataset / "data").is_dir():
        collect_dataset(dataset, args.dataset_episodes, seed=1_000_000, overwrite=True)  # fig2's seed 0
    print(f"dataset: {load_dataset(dataset).total_steps} transitions")
    units = peer_units(args.work, dataset, args.online_steps, args.offline_steps, args.eval_episodes)
    records = {r.name: r.value for r in run_units(units, ProcessExecutor(1))}
    print(f"\nper unit at {args.online_steps} online steps, {args.offline_steps} offline steps, "
          f"{args.eval_episodes} evaluation episodes (wall s / CPU s per phase):")
    full = {}
    for arm in ARMS:
        rec = records[arm]
        phases = ", ".join(f"{k} {rec['wall_seconds'][k]:.1f}/{rec['cpu_seconds'][k]:.1f}"
                           for k in rec["cpu_seconds"] if k != "total")
        full[arm] = full_unit_seconds(rec, args.full_online_steps, args.full_offline_steps, args.eval_episodes)
        print(f"  {arm:16s} total {rec['wall_seconds']['total']:7.1f} / {rec['cpu_seconds']['total']:7.1f}  ({phases})"
              f"  reward {rec['evaluation']['summary']['reward']:.2f}")
    print(f"\nestimate at {args.full_online_steps} online steps and {args.full_offline_steps} offline steps "
          f"(CPU seconds per unit, one core each):")
    for arm in ARMS:
        print(f"  {arm:16s} {full[arm]:8.0f} s")
    table = sum(full.values()) * args.seeds / args.workers
    print(f"peer arms x {args.seeds} seeds on {args.workers} cores: {table / 60:.0f} min wall "
          "(plus the UA2C arms, estimated by fig2)")


if __name__ == "__main__":
    main()
