"""Re-measure the velocity-field coefficients of ``fig2``'s cost estimate, next to SB3 SAC.

Usage::

    python -m experiments.fig2.measure_costs                     # 128x2, 3x256, 3x512 on MixedTraffic-v0
    python -m experiments.fig2.measure_costs --net-arch 128,128 512,512,512 --steps 100

For every ``net_arch`` it times, on ``MixedTraffic-v0`` with one torch thread:

- a Phase-1 gradient step (``UA2C.pretrain``, batch 256) of the one-step (k = 1) and chunk (k = 5)
  policies, on episodes of the default behaviour policy;
- one replanning of the k = 5 policy (``predict`` at an episode start: S candidates, N Euler steps);
- the peer: one SB3 SAC gradient step (``SAC.train``, batch 256) with the same ``net_arch``.

It prints the times, the ratios UA2C / SAC and measured / estimated, where "estimated" is what
:class:`experiments.fig2.budget.CostModel` predicts (the numbers behind ``python -m experiments.fig2``'s
printed estimate), and the least-squares slopes of the k = 5 step and of the replanning over the
velocity field's extra weights: the values of ``update_ms_per_kweight`` and ``plan_ms_per_kweight``
on this machine. Times are medians of the calling thread's CPU time, so a second process sharing
the cores slows them little; read the ratios.
"""

from __future__ import annotations

import argparse
import platform

import numpy as np
import torch as th
from bench_ua2c import cpu_ms  # benchmarks/ is on sys.path when run as a script
from stable_baselines3 import SAC

from envs.collection import TRAFFIC_DEFAULTS, collect_episodes, make_traffic_env
from experiments.fig2.budget import CostModel, extra_kweights, velocity_field_weights
from sb3_ua2c import UA2C


def estimated_ms(costs: CostModel, net_arch: list[int]) -> dict[str, float]:
    """The cost model's step and replanning times for ``net_arch`` (what ``estimate_seconds`` adds)."""
    extra = extra_kweights({"policy_kwargs": {"net_arch": net_arch}})
    return {"k1": costs.pretrain_step_ms(1, extra), "k5": costs.pretrain_step_ms(5, extra), "plan": costs.replan_ms(extra)}


def slope(x: list[float], y: list[float]) -> float:
    """Least-squares slope of ``y`` over ``x`` (ms per 1,000 weights)."""
    return float(np.polyfit(np.asarray(x), np.asarray(y), 1)[0]) if len(set(x)) > 1 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--net-arch", nargs="+", default=["128,128", "256,256,256", "512,512,512"])
    parser.add_argument("--steps", type=int, default=60, help="timed gradient steps per arm (median of single steps)")
    parser.add_argument("--plans", type=int, default=50, help="timed replannings")
    parser.add_argument("--episodes", type=int, default=4, help="behaviour episodes in the replay buffer")
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"torch {th.__version__}, {platform.processor() or platform.machine()}, 1 thread")
    env = make_traffic_env()
    try:
        episodes = collect_episodes(env, args.episodes, seed=0)
        obs, _ = env.reset(seed=0)
        costs, rows = CostModel(), []
        for arch in args.net_arch:
            net_arch = [int(h) for h in arch.split(",")]
            row = {"arch": "x".join(map(str, net_arch)), "kweights": velocity_field_weights({"policy_kwargs": {"net_arch": net_arch}}) / 1000}
            models = {}
            for k in (1, 5):
                models[k] = UA2C("MlpPolicy", env, seed=0, device="cpu", chunk_size=k, policy_kwargs={"net_arch": net_arch}, **TRAFFIC_DEFAULTS)
                models[k].add_offline_episodes(episodes)
                row[f"k{k}"] = cpu_ms(lambda m=models[k]: m.pretrain(1, log_interval=10**9), args.steps)
            start = np.array([True])  # every call replans
            row["plan"] = cpu_ms(lambda m=models[5], s=start: m.predict(obs, episode_start=s, deterministic=True), args.plans)
            sac = SAC("MlpPolicy", env, seed=0, device="cpu", batch_size=256, learning_starts=300, policy_kwargs={"net_arch": net_arch})
            sac.learn(301)  # fills the buffer and sets up the logger; one update
            row["sac"] = cpu_ms(lambda s=sac: s.train(gradient_steps=1, batch_size=256), args.steps)
            row["est"] = estimated_ms(costs, net_arch)
            rows.append(row)
            print(f"  {row['arch']}: done", flush=True)
    finally:
        env.close()

    print()
    print("| net_arch | hidden weights [k] | UA2C k=1 [ms] | UA2C k=5 [ms] | replanning k=5 [ms] | SAC step [ms] "
          "| k=5 / SAC | k=1 meas/est | k=5 meas/est | replanning meas/est |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        e = r["est"]
        print(
            f"| {r['arch']} | {r['kweights']:.1f} | {r['k1']:.1f} | {r['k5']:.1f} | {r['plan']:.2f} | {r['sac']:.1f} "
            f"| {r['k5'] / r['sac']:.2f} | {r['k1'] / e['k1']:.2f} | {r['k5'] / e['k5']:.2f} | {r['plan'] / e['plan']:.2f} |"
        )
    x = [r["kweights"] for r in rows]
    print()
    print(f"update_ms_per_kweight on this machine (slope of the k=5 step): {slope(x, [r['k5'] for r in rows]):.4f} "
          f"(CostModel: {costs.update_ms_per_kweight})")
    print(f"plan_ms_per_kweight on this machine (slope of the replanning): {slope(x, [r['plan'] for r in rows]):.4f} "
          f"(CostModel: {costs.plan_ms_per_kweight})")


if __name__ == "__main__":
    main()
