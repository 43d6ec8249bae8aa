"""Where a chunk policy schedules its lane changes, and whether the executed prefix reaches them.

Usage::

    python -m experiments lane-change-timing CHECKPOINT.zip --dataset DATASET_DIR [--eval-seed 2002]
        [--episodes 6] [--delta 0]

Runs one checkpoint on the same scenarios under three execution rules, side by side: fixed chunks
(δ = inf), Eq. 7 with δ, and Eq. 7 with ``commit_discrete=True``. For every rule it prints the mean
return, the merge rate, the mean L_t and, over the plans whose selected chunk switches lanes
(first categorical switch ``u*`` of :func:`sb3_ua2c.chunking.commit_through_switch`), how many
plans there were, the share whose switch lies inside the executed prefix (``u* < L_t``), the mean
``u*``, and the lane-change actions actually executed. A policy that replans before its planned
change postpones it, plan after plan: many planned switches, a share near 0, no change executed
and no merge.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch as th

from envs.collection import make_traffic_env
from sb3_ua2c import UA2C
from sb3_ua2c.chunking import categorize, commit_through_switch
from sb3_ua2c.offline import load_dataset
from sb3_ua2c.pipeline import env_settings


def first_switch(plan: np.ndarray, discrete_dims: dict[int, int]) -> int | None:
    """``u*``: the first position ``u >= 1`` where a categorical dim of ``plan`` (k, A) changes category."""
    committed = int(commit_through_switch(th.ones(1, dtype=th.long), th.as_tensor(plan[None]), discrete_dims)[0])
    return committed - 1 if committed > 1 else None  # L_t = 1 committed through u* gives u* + 1


def run_rule(model: UA2C, env, seeds: list[int]) -> dict[str, float]:
    dims = model.policy.discrete_dims
    returns, merges, lengths, switch_pos, inside, executed = [], [], [], [], [], 0
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        state, start, done, total, merged = None, np.array([True]), False, 0.0, False
        while not done:
            action, state = model.predict(obs, state=state, episode_start=start, deterministic=True)
            normalized = model.policy.scale_action(np.asarray(action, dtype=np.float32)[None])[0]
            # a lane change executed: a categorical dim off its middle category (keep lane)
            executed += int(any(categorize(th.tensor(normalized[d]), n).item() != n // 2 for d, n in dims.items()))
            if int(state.plan_position[0]) == 1:  # a plan was made at this step
                length = int(state.plan_length[0])
                lengths.append(length)
                u = first_switch(state.plan[0], dims)
                if u is not None:
                    switch_pos.append(u)
                    inside.append(u < length)
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            merged |= bool(info.get("merge_done", False))
            start, done = np.array([False]), terminated or truncated
        returns.append(total)
        merges.append(merged)
    return {
        "return": float(np.mean(returns)),
        "merge": float(np.mean(merges)),
        "mean L_t": float(np.mean(lengths)),
        "plans with a switch": float(len(switch_pos)),
        "switch inside prefix": float(np.mean(inside)) if inside else math.nan,
        "mean u*": float(np.mean(switch_pos)) if switch_pos else math.nan,
        "lane changes executed": float(executed),
    }


def main(argv: list[str] | None = None, prog: str | None = None) -> None:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--dataset", required=True, help="the dataset the checkpoint was trained on (env settings)")
    parser.add_argument("--eval-seed", type=int, default=2002, help="scenarios 1000 * seed + i (fig2: 2000 + seed)")
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--delta", type=float, default=0.0)
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    env = make_traffic_env(**env_settings(load_dataset(args.dataset)))
    seeds = [1000 * args.eval_seed + i for i in range(args.episodes)]
    rules = {
        "fixed (δ = inf)": dict(entropy_threshold=math.inf, commit_discrete=False),  # same as default: vs commit
        f"Eq. 7 (δ = {args.delta:g})": dict(entropy_threshold=args.delta, commit_discrete=False),  # same as default: vs commit
        f"Eq. 7 + commit (δ = {args.delta:g})": dict(entropy_threshold=args.delta, commit_discrete=True),
    }
    try:
        rows = {name: run_rule(UA2C.load(args.checkpoint, **kw), env, seeds) for name, kw in rules.items()}
    finally:
        env.close()
    keys = list(next(iter(rows.values())))
    print("| rule | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{row[k]:.2f}" for k in keys) + " |")
