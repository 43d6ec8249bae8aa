"""The three stages of a head-to-head run: datasets, the UA2C arms' checkpoints, and one unit per arm and seed."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from experiments.common import records
from experiments.common.names import DATASET_SEED_BASE, SCENARIO_BASES
from experiments.common.runner import Executor, Unit, UnitResult, run_units
from experiments.peers import run_d3rlpy, run_sb3_offline_mix, run_sb3_online
from experiments.peers.budget import D3RLPY_ARMS, ONLINE_SB3_ARMS, UA2C_ARMS, PeersBudget, estimate_units
from experiments.peers.common import ArmInputs, run_behaviour
from experiments.peers.ua2c_arms import build_checkpoint, build_dataset, run_ua2c_arm


class PeersPaths(records.RunPaths):
    """:class:`~experiments.common.records.RunPaths` of a head-to-head: one JSON record per (arm, seed) in ``raw``."""

    NAME = "peers"
    BUDGET = PeersBudget

    def record(self, seed: int, arm: str) -> Path:
        return self.raw / f"seed{seed}" / f"{arm}.json"


def dataset_units(seeds: Sequence[int], budget: PeersBudget, paths: PeersPaths) -> list[Unit]:
    b = budget.ua2c
    return [Unit(f"seed{s}/dataset", build_dataset,
                 {"path": str(paths.seed_work(s) / "dataset"), "n_episodes": b.dataset_episodes,
                  "seed": DATASET_SEED_BASE + 10_000 * s, "env_kwargs": dict(b.env_kwargs)},
                 paths.seed_work(s) / "dataset.json") for s in seeds]


def pretrain_units(seeds: Sequence[int], arms: Sequence[str], budget: PeersBudget, paths: PeersPaths) -> list[Unit]:
    ua2c_arms = {budget.pretrain_name(a): a for a in arms if a in UA2C_ARMS}  # one arm per checkpoint
    b = budget.ua2c
    return [Unit(f"seed{s}/{name}", build_checkpoint,
                 {"dataset": str(paths.seed_work(s) / "dataset"), "out": str(paths.seed_work(s) / f"{name}.zip"),
                  "pretrain_steps": b.pretrain_steps, "seed": s, "algo_kwargs": budget.pretrain_kwargs(arm)},
                 paths.seed_work(s) / f"{name}.json") for s in seeds for name, arm in sorted(ua2c_arms.items())]


def arm_unit(arm: str, seed: int, budget: PeersBudget, paths: PeersPaths, pretrained: dict[str, Any],
             snapshot_every: int = 0) -> Unit:
    """The unit of ``arm`` on ``seed`` (``pretrained``: the records of stage 2 by unit name; ``snapshot_every``: save
    UA2C arms every that many online steps, see :func:`~experiments.peers.ua2c_arms.run_ua2c_arm`)."""
    inputs = ArmInputs(out_dir=str(paths.seed_work(seed) / arm), dataset=str(paths.seed_work(seed) / "dataset"),
                       seed=seed, online_steps=budget.online_steps,
                       eval_seeds=(SCENARIO_BASES[budget.scenarios] + seed,), eval_episodes=budget.ua2c.eval_episodes)
    fn: Callable[..., Any]
    if arm in UA2C_ARMS:
        record = pretrained[f"seed{seed}/{budget.pretrain_name(arm)}"]
        fn, kwargs = run_ua2c_arm, {"arm": arm, "checkpoint": record["checkpoint"], "delta": budget.delta(arm),
                                    "finetune_overrides": budget.finetune_overrides(arm), "pretrain_record": record,
                                    "snapshot_every": snapshot_every}
    elif arm in ONLINE_SB3_ARMS:
        fn, kwargs = run_sb3_online, {"algo": arm, "hyperparams": budget.sb3_kwargs(arm)}
    elif arm == "sac_offline_mix":
        fn, kwargs = run_sb3_offline_mix, {"hyperparams": budget.sb3_kwargs(arm)}
    elif arm == "behaviour":
        fn, kwargs = run_behaviour, {}
    elif arm in D3RLPY_ARMS:
        fn, kwargs = run_d3rlpy, {"algo": arm, "offline_steps": budget.offline_steps(arm),
                                  "batch_size": budget.d3rlpy_batch_size,
                                  "updates_per_step": budget.updates_per_step(arm),
                                  "best_of_n": budget.iql_best_of_n if arm == "iql" else 0,
                                  "config_kwargs": budget.peer_kwargs.get(arm, {})}
    else:
        raise ValueError(f"arms: unknown arm {arm!r}")
    return Unit(f"seed{seed}/{arm}", fn, {"inputs": inputs, **kwargs}, paths.record(seed, arm))


def run_peers(seeds: Sequence[int], arms: Sequence[str], budget: PeersBudget, paths: PeersPaths, executor: Executor,
              printer: Callable[[str], Any] | None = print, snapshot_every: int = 0) -> list[UnitResult]:
    """Run (or resume) the three stages, the arm units most expensive first; return the arm units' results."""
    paths.check_budget(budget)
    for s in seeds:
        paths.seed_work(s).mkdir(parents=True, exist_ok=True)
    run_units(dataset_units(seeds, budget, paths), executor, printer)
    pretrained = {r.name: r.value for r in run_units(pretrain_units(seeds, arms, budget, paths), executor, printer)}
    cost = estimate_units(budget, arms, len(seeds), workers=1)["per_unit"]
    order = sorted(((a, s) for s in seeds for a in arms), key=lambda p: (-cost[p[0]], p[1]))
    return run_units([arm_unit(a, s, budget, paths, pretrained, snapshot_every) for a, s in order], executor, printer)


def load_records(paths: PeersPaths, seeds: Sequence[int] | None = None) -> dict[str, list[dict[str, Any]]]:
    """The stored arm records by arm (any arm, the given seeds or every ``seed<s>`` directory in ``raw``)."""
    out: dict[str, list[dict[str, Any]]] = {}
    dirs = sorted(paths.raw.glob("seed*")) if seeds is None else [paths.raw / f"seed{s}" for s in seeds]
    for d in dirs:
        for f in sorted(d.glob("*.json")):
            record = json.loads(f.read_text())
            out.setdefault(record["arm"], []).append(record)
            if record.get("evaluation_best_of_n"):  # the same policy acting by best-of-N: a row of its own
                # (its training is the base arm's: no learning curve of its own)
                best = {**record, "arm": f"{record['arm']}_best_of_n", "evaluation": record["evaluation_best_of_n"],
                        "offline_evaluation": None, "online_episodes": []}
                out.setdefault(best["arm"], []).append(best)
    return out
