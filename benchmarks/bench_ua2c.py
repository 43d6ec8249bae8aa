"""UA2C speed and learning benchmarks, each next to SB3 SAC measured in the same run.

    python benchmarks/bench_ua2c.py latency      # replanning (S=32, k=10, N=10) vs SAC predict
    python benchmarks/bench_ua2c.py throughput   # learn() env steps/s on Pendulum-v1, default hyperparameters
    python benchmarks/bench_ua2c.py throughput --ua2c-kwargs "{'policy_kwargs': {'torch_compile': True}}"
    python benchmarks/bench_ua2c.py throughput --env envs:MixedTraffic-v0   # the SUMO env, both at defaults
    python benchmarks/bench_ua2c.py learning     # mean return after 20k steps, 3 seeds each
    python benchmarks/bench_ua2c.py learning --algos UA2C --ua2c-kwargs "{'chunk_size': 1}"

Everything runs on one CPU thread. The machine may be shared: read the ratios, not the absolute times.
"""

from __future__ import annotations

import argparse
import ast
import platform
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.evaluation import evaluate_policy
from torch.utils.flop_counter import FlopCounterMode

from sb3_ua2c import UA2C
from sb3_ua2c.chunking import chunk_entropy

ENV_ID = "Pendulum-v1"


def median_ms(fn: Callable[[], object], repeats: int, warmup: int = 20) -> float:
    """Median wall-clock time of ``fn`` in ms (see :func:`cpu_ms` on a loaded machine)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def cpu_ms(fn: Callable[[], object], repeats: int, warmup: int = 20) -> float:
    """Median CPU time of the calling thread in ms: unaffected by time slicing when other processes
    share the cores (wall-clock medians then penalise long calls more than short ones)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.thread_time()
        fn()
        times.append(time.thread_time() - start)
    return 1e3 * statistics.median(times)


def flops(fn: Callable[[], object]) -> int:
    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


def latency(repeats: int, ua2c_kwargs: dict) -> None:
    """One replanning of UA2C (S=32 candidates, k=10, N=10 Euler steps unless ``ua2c_kwargs`` say
    otherwise; min-Q selection, entropy, prefix length) next to SAC's predict on the same observation."""
    env = gym.make(ENV_ID)
    obs, _ = env.reset(seed=0)
    ua2c = UA2C("MlpPolicy", ENV_ID, seed=0, **{"chunk_size": 10, "n_candidates": 32, "flow_steps": 10, **ua2c_kwargs})
    sac = SAC("MlpPolicy", ENV_ID, seed=0)
    policy = ua2c.policy
    obs_h = np.repeat(obs[None, None], ua2c.history_len, axis=1).astype(np.float32)  # (1, ℓ, obs_dim)
    act_h = np.zeros((1, ua2c.history_len, policy.action_dim), np.float32)
    plan_ms = median_ms(lambda: policy.plan(obs_h, act_h), repeats)
    sac_ms = median_ms(lambda: sac.predict(obs, deterministic=True), repeats)
    plan_cpu = cpu_ms(lambda: policy.plan(obs_h, act_h), repeats)
    sac_cpu = cpu_ms(lambda: sac.predict(obs, deterministic=True), repeats)
    # per env step with the executor state (replans only when the prefix is used up)
    state = {"s": None}

    def step() -> None:
        _, state["s"] = ua2c.predict(obs, state=state["s"], episode_start=np.array([False]))

    step_ms = median_ms(step, repeats)
    obs_t = th.as_tensor(obs_h)
    act_t = th.as_tensor(act_h)
    with th.inference_mode():
        plan_flops = flops(lambda: policy.plan_tensors(obs_t, act_t))
        sac_flops = flops(lambda: sac.policy.actor(th.as_tensor(obs[None]), deterministic=True))
        parts = _plan_parts(policy, obs_t, act_t, repeats)
    print(
        f"replanning UA2C (S={policy.n_candidates}, k={ua2c.chunk_size}, N={policy.flow_steps}): median {plan_ms:.3f} ms wall, {plan_cpu:.3f} ms CPU, "
        f"{plan_flops / 1e6:.2f} MFLOP = {plan_flops / plan_cpu / 1e6:.1f} GFLOP/s (goal <= 0.6 ms wall)"
    )
    print("  of which (ms CPU): " + ", ".join(f"{name} {ms:.3f}" for name, ms in parts.items()))
    print(f"UA2C predict() per env step with state: median {step_ms:.3f} ms wall")
    print(f"SAC predict: median {sac_ms:.3f} ms wall, {sac_cpu:.3f} ms CPU, {sac_flops / 1e6:.3f} MFLOP")
    print(
        f"ratio replanning / SAC predict: {plan_ms / sac_ms:.1f}x wall, {plan_cpu / sac_cpu:.1f}x CPU "
        "(goal: replanning <= 0.6 ms wall)"
    )


def _plan_parts(policy, obs_t: th.Tensor, act_t: th.Tensor, repeats: int) -> dict[str, float]:
    """CPU ms of the parts of one replanning: flow sampler (N Euler steps), entropy, critic scoring."""
    m = obs_t.shape[0]
    samples = policy.sample_chunks(obs_t, act_t, policy.n_candidates, policy.flow_steps)
    clipped = samples.clamp(-1.0, 1.0)
    return {
        "sampler": cpu_ms(lambda: policy.sample_chunks(obs_t, act_t, policy.n_candidates, policy.flow_steps), repeats),
        "entropy": cpu_ms(
            lambda: chunk_entropy(samples, policy.discrete_dims, discrete=policy.discrete_entropy), repeats
        ),
        "critics": cpu_ms(lambda: policy.critic(obs_t.reshape(m, -1), clipped), repeats),
    }


def _throughput(model: UA2C | SAC, warm_steps: int, steps: int) -> tuple[float, float, int]:
    """Env steps per wall-clock second and per CPU second of ``learn(steps)`` after a warm-up."""
    model.learn(warm_steps)
    n0 = model._n_updates
    wall, cpu = time.perf_counter(), time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return steps / wall, steps / cpu, model._n_updates - n0


def throughput(steps: int, ua2c_kwargs: dict, env_id: str = ENV_ID) -> None:
    """learn() env steps/s including training, at default hyperparameters, after each warm-up. The two
    models run one after the other, each env closed before the next opens (a SUMO env holds its
    process's one simulation)."""
    print(f"env {env_id}")
    ua2c = UA2C("MlpPolicy", env_id, seed=0, **ua2c_kwargs)
    start = time.perf_counter()
    ua2c_fps, ua2c_cpu_fps, ua2c_updates = _throughput(ua2c, ua2c.learning_starts + 200, steps)
    if ua2c.policy.torch_compile:  # compiled during the warm-up's first plans and updates
        print(
            f"UA2C torch_compile: warm-up ({ua2c.learning_starts + 200} steps) and timed learn() took "
            f"{time.perf_counter() - start:.1f} s wall, compilation included"
        )
    ua2c.env.close()
    sac = SAC("MlpPolicy", env_id, seed=0)
    sac_fps, sac_cpu_fps, sac_updates = _throughput(sac, sac.learning_starts + 200, steps)
    sac.env.close()
    data = ua2c.replay_buffer.sample(ua2c.batch_size)
    ua2c_step_ms = cpu_ms(lambda: ua2c._gradient_step(data), 20, warmup=3)
    sac_step_ms = cpu_ms(lambda: sac.train(1, sac.batch_size), 20, warmup=3)
    ua2c_flops = flops(lambda: ua2c._gradient_step(data))
    sac_flops = flops(lambda: sac.train(1, sac.batch_size))
    ua2c_gflops, sac_gflops = ua2c_flops / ua2c_step_ms / 1e6, sac_flops / sac_step_ms / 1e6
    print(
        f"UA2C: {ua2c_fps:.1f} env steps/s wall, {ua2c_cpu_fps:.1f} per CPU s, {ua2c_updates / steps:.2f} gradient steps per env step, "
        f"gradient step {ua2c_step_ms:.1f} ms CPU / {ua2c_flops / 1e9:.2f} GFLOP = {ua2c_gflops:.1f} GFLOP/s, "
        f"mean L_t {ua2c.last_executed_length:.2f}"
    )
    print(
        f"SAC:  {sac_fps:.1f} env steps/s wall, {sac_cpu_fps:.1f} per CPU s, {sac_updates / steps:.2f} gradient steps per env step, "
        f"gradient step {sac_step_ms:.1f} ms CPU / {sac_flops / 1e9:.2f} GFLOP = {sac_gflops:.1f} GFLOP/s"
    )
    print(
        f"ratio UA2C / SAC: throughput {ua2c_fps / sac_fps:.2f} wall, {ua2c_cpu_fps / sac_cpu_fps:.2f} CPU (goal >= 1.0); "
        f"gradient step {ua2c_step_ms / sac_step_ms:.2f}x the time, {ua2c_gflops / sac_gflops:.2f}x the GFLOP/s "
        "(goal >= 40 GFLOP/s)"
    )


def learning(steps: int, seeds: list[int], eval_episodes: int, algos: list[str], ua2c_kwargs: dict) -> None:
    """Mean deterministic return after ``steps`` env steps, SAC at default hyperparameters and UA2C at
    its defaults updated with ``ua2c_kwargs``."""
    classes = {"UA2C": UA2C, "SAC": SAC}
    if ua2c_kwargs:
        print(f"UA2C arguments: {ua2c_kwargs}")
    results: dict[str, list[float]] = {name: [] for name in algos}
    lengths = []
    for seed in seeds:
        for name in algos:
            cls = classes[name]
            start = time.perf_counter()
            kwargs = ua2c_kwargs if cls is UA2C else {}
            model = cls("MlpPolicy", ENV_ID, seed=seed, **kwargs)
            model.learn(steps)
            eval_env = gym.make(ENV_ID)
            eval_env.reset(seed=10_000 + seed)
            mean, std = evaluate_policy(
                model, eval_env, n_eval_episodes=eval_episodes, deterministic=True, warn=False
            )
            results[name].append(float(mean))
            extra = ""
            if isinstance(model, UA2C):
                lengths.append(model.last_executed_length)
                extra = f", mean L_t {model.last_executed_length:.2f}"
            print(
                f"{name} seed {seed}: {mean:.1f} +/- {std:.1f} ({time.perf_counter() - start:.0f} s{extra})",
                flush=True,
            )
    for name, values in results.items():
        print(
            f"{name}: mean return after {steps} steps over seeds {seeds}: {np.mean(values):.1f} "
            f"(min {np.min(values):.1f}, max {np.max(values):.1f})"
        )
    if lengths:
        print(f"UA2C mean executed length L_t: {np.mean(lengths):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("part", choices=["latency", "throughput", "learning"])
    parser.add_argument("--repeats", type=int, default=300, help="latency: timed calls")
    parser.add_argument(
        "--steps", type=int, default=None, help="throughput: 1000 timed steps; learning: 20000"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument(
        "--ua2c-kwargs",
        type=ast.literal_eval,
        default={},
        help="latency, throughput and learning: UA2C arguments, e.g. \"{'chunk_size': 1}\"",
    )
    parser.add_argument(
        "--env", default=ENV_ID, help="throughput: env id (module:id imports the module first, e.g. envs:MixedTraffic-v0)"
    )
    parser.add_argument("--algos", nargs="+", choices=["UA2C", "SAC"], default=["UA2C", "SAC"])
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"torch {th.__version__}, {platform.processor() or platform.machine()}, 1 thread")
    if args.part == "latency":
        latency(args.repeats, args.ua2c_kwargs)
    elif args.part == "throughput":
        throughput(args.steps or 1000, args.ua2c_kwargs, args.env)
    else:
        learning(args.steps or 20_000, args.seeds, args.eval_episodes, args.algos, args.ua2c_kwargs)


if __name__ == "__main__":
    main()
