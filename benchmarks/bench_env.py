"""Speed of ``MixedTraffic-v0`` next to a bare SUMO loop of the same scenario and highway-env.

Usage::

    python benchmarks/bench_env.py [--steps 6000] [--seed 0]

Prints, all measured in this run in one process:

* env steps/s with a uniformly random policy, resets included;
* the same scenario stepped with bare ``libsumo.simulationStep()`` (same start states, no
  observation / reward / re-entry work), and the ratio env step time / bare step time;
* simulated seconds per wall-clock second of both, and of highway-env's ``merge-v0`` (when
  installed; one of its steps is ``1 / policy_frequency`` simulated seconds).
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import envs  # noqa: F401  (registers MixedTraffic-v0)


def bench_env(steps: int, seed: int) -> tuple[float, float, int]:
    """Random policy incl. resets. Returns (steps/s, seconds in reset, episodes)."""
    env = gym.make("MixedTraffic-v0").unwrapped
    rng = np.random.default_rng(seed)
    actions = rng.uniform(env.action_space.low, env.action_space.high, size=(steps, 2)).astype(np.float32)
    t_reset = time.perf_counter()
    env.reset(seed=seed)
    reset_time = time.perf_counter() - t_reset
    episodes = 1
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            t0 = time.perf_counter()
            env.reset()
            reset_time += time.perf_counter() - t0
            episodes += 1
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed, reset_time, episodes


def bench_bare(steps: int, seed: int, episode_steps: int) -> tuple[float, float]:
    """Same start states, then only ``simulationStep``. Returns (steps/s incl. resets, step-only steps/s)."""
    env = gym.make("MixedTraffic-v0").unwrapped
    done = 0
    step_time = 0.0
    start = time.perf_counter()
    env.reset(seed=seed)  # starts SUMO
    libsumo = env.sim.libsumo
    while done < steps:
        n = min(episode_steps, steps - done)
        t0 = time.perf_counter()
        for _ in range(n):
            libsumo.simulationStep()
        step_time += time.perf_counter() - t0
        done += n
        if done < steps:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed, steps / step_time


def bench_env_step_only(steps: int, seed: int) -> float:
    """Env steps/s excluding resets (for the overhead ratio against the bare loop)."""
    env = gym.make("MixedTraffic-v0").unwrapped
    rng = np.random.default_rng(seed)
    # Keep the AV in its lane at a mild acceleration, so that episodes run to the time limit.
    env.reset(seed=seed)
    step_time, done = 0.0, 0
    while done < steps:
        t0 = time.perf_counter()
        a = np.array([rng.uniform(-1.0, 1.0), 0.0], dtype=np.float32)
        _, _, terminated, truncated, _ = env.step(a)
        step_time += time.perf_counter() - t0
        done += 1
        if terminated or truncated:
            env.reset()
    env.close()
    return steps / step_time


def bench_highway_env(steps: int, seed: int) -> tuple[float, float] | None:
    """highway-env merge-v0 with a random policy. Returns (steps/s, simulated s per step) or None."""
    try:
        import highway_env  # noqa: F401
    except ImportError:
        return None
    env = gym.make("merge-v0")
    env.reset(seed=seed)
    env.action_space.seed(seed)
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    sim_dt = 1.0 / env.unwrapped.config["policy_frequency"]
    env.close()
    return steps / elapsed, sim_dt


def reward_breakdown(steps: int, seed: int) -> tuple[dict[str, float], int, int]:
    """Mean weighted reward term per step of a random policy, episodes, and collisions."""
    env = gym.make("MixedTraffic-v0").unwrapped
    env.reset(seed=seed)
    env.action_space.seed(seed)
    totals: dict[str, float] = {}
    episodes = collisions = 0
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        for name, value in info["reward_terms"].items():
            totals[name] = totals.get(name, 0.0) + value
        if terminated or truncated:
            episodes += 1
            collisions += int(info["collision"])
            env.reset()
    env.close()
    return {name: value / steps for name, value in totals.items()}, episodes, collisions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--highway-steps", type=int, default=200)
    args = parser.parse_args()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    dt = envs.MixedTrafficConfig().step_length
    episode_steps = envs.MixedTrafficConfig().max_episode_steps

    env_sps, reset_s, episodes = bench_env(args.steps, args.seed)
    env_step_sps = bench_env_step_only(args.steps, args.seed)
    bare_sps, bare_step_sps = bench_bare(args.steps, args.seed, episode_steps)
    print(f"MixedTraffic-v0, random policy incl. resets : {env_sps:8.0f} steps/s "
          f"({episodes} episodes, {1000 * reset_s / episodes:.1f} ms per reset) "
          f"= {env_sps * dt:7.0f} simulated s / s")
    print(f"MixedTraffic-v0, steps only                 : {env_step_sps:8.0f} steps/s")
    print(f"bare libsumo simulationStep, same scenario  : {bare_step_sps:8.0f} steps/s "
          f"({bare_sps:.0f} steps/s incl. resets)")
    print(f"env overhead: env step time / bare step time = {bare_step_sps / env_step_sps:.2f}x")
    terms, n_eps, n_col = reward_breakdown(args.steps // 2, args.seed)
    print(f"random policy, mean weighted reward term per step ({n_eps} episodes, {n_col} collisions):")
    print("  " + ", ".join(f"{name} {value:+.3f}" for name, value in terms.items()))
    hw = bench_highway_env(args.highway_steps, args.seed)
    if hw is None:
        print("highway-env not installed: merge-v0 comparison skipped")
    else:
        hw_sps, hw_dt = hw
        print(f"highway-env merge-v0, random policy         : {hw_sps:8.1f} steps/s "
              f"= {hw_sps * hw_dt:7.1f} simulated s / s")
        print(f"MixedTraffic-v0 / merge-v0 simulated seconds per wall second = "
              f"{env_sps * dt / (hw_sps * hw_dt):.1f}x")


if __name__ == "__main__":
    main()
