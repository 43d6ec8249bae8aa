"""UA2C speed and learning benchmarks, each next to SB3 SAC measured in the same run.

    python benchmarks/bench_ua2c.py latency      # replanning (S=32, k=10, the defaults' N) vs SAC predict
    python benchmarks/bench_ua2c.py throughput   # learn() env steps/s on Pendulum-v1, default hyperparameters
    python benchmarks/bench_ua2c.py throughput --ua2c-kwargs "{'policy_kwargs': {'torch_compile': True}}"
    python benchmarks/bench_ua2c.py throughput --env envs:MixedTraffic-v0   # the SUMO env, both at defaults
    python benchmarks/bench_ua2c.py learning     # mean return after 20k steps, 3 seeds each
    python benchmarks/bench_ua2c.py learning --seeds 0 1 2 3 4 --json results/pendulum/pendulum.json
    python benchmarks/bench_ua2c.py learning --algos UA2C --ua2c-kwargs "{'chunk_size': 1}"
    python benchmarks/bench_ua2c.py merge --inputs part1.json part2.json --json all.json   # runs split by seed
    python benchmarks/bench_ua2c.py profile --env envs:MixedTraffic-v0   # where a step and a replanning go

Everything runs on one CPU thread. The machine may be shared: read the ratios, not the absolute times.
"""

from __future__ import annotations

import argparse
import ast
import json
import platform
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.evaluation import evaluate_policy
from torch.utils.flop_counter import FlopCounterMode

from sb3_ua2c import UA2C
from sb3_ua2c.chunking import chunk_entropy
from sb3_ua2c.diagnostics import DIAGNOSTICS_INTERVAL
from sb3_ua2c.presets import preset

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
    """One replanning of UA2C (S=32 candidates, k=10, the defaults' Euler steps N unless ``ua2c_kwargs`` say
    otherwise; min-Q selection, entropy, prefix length) next to SAC's predict on the same observation."""
    env = gym.make(ENV_ID)
    obs, _ = env.reset(seed=0)
    ua2c = UA2C("MlpPolicy", ENV_ID, seed=0, **{"chunk_size": 10, "n_candidates": 32, **ua2c_kwargs})
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


def _skip_diagnostics_update(model: UA2C, update: int) -> None:
    """Make one update first when update number ``update`` would also log the diagnostics (one in
    ``DIAGNOSTICS_INTERVAL``), so that the updates timed and counted next are ordinary ones."""
    if update % DIAGNOSTICS_INTERVAL == 0:
        model.train(1, model.batch_size)


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
    # one update as learn() makes it, batch sampling included, for both (train() numbers an update before
    # making it); the UA2C update that logs the diagnostics is outside the median and not counted
    ua2c_step_ms = cpu_ms(lambda: ua2c.train(1, ua2c.batch_size), 20, warmup=3)
    sac_step_ms = cpu_ms(lambda: sac.train(1, sac.batch_size), 20, warmup=3)
    _skip_diagnostics_update(ua2c, ua2c._n_updates + 1)
    ua2c_flops = flops(lambda: ua2c.train(1, ua2c.batch_size))
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


def learning(steps: int, seeds: list[int], eval_episodes: int, algos: list[str], ua2c_kwargs: dict,
             json_path: str | None = None) -> None:
    """Mean deterministic return after ``steps`` env steps, SAC at default hyperparameters and UA2C at
    its defaults updated with ``ua2c_kwargs``; ``json_path``: also write ``{"ua2c": [per-seed mean
    return], "sac": [...], "seeds": [...], ...}`` there."""
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
    if json_path:
        record = {name.lower(): values for name, values in results.items()}
        record |= {"seeds": seeds, "steps": steps, "eval_episodes": eval_episodes, "env": ENV_ID,
                   "ua2c_kwargs": ua2c_kwargs,
                   "ua2c_mean_executed_length": [None if np.isnan(v) else v for v in lengths],
                   "command": shlex.join(["python", *sys.argv]), "torch": th.__version__,
                   "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps(record, indent=1) + "\n")


def merge(inputs: list[str], json_path: str) -> None:
    """One ``learning --json`` record from several that ran the same protocol on other seeds or algorithms
    (e.g. in parallel processes): per algorithm its returns in seed order, the parts' commands kept."""
    files = [(f, json.loads(Path(f).read_text())) for f in inputs]
    parts = [part for _, part in files]
    protocol = ("steps", "eval_episodes", "env", "torch")
    with_ua2c = [(f, part) for f, part in files if part.get("ua2c")]
    _check_same(files, protocol)
    _check_same(with_ua2c, ("ua2c_kwargs",))  # UA2C's arguments: the parts that ran it only
    by_seed: dict[str, dict[int, float | None]] = {}
    for part in parts:
        names = [k for k in part if isinstance(part[k], list) and k not in ("seeds", "ua2c_mean_executed_length")]
        for name in names:
            for seed, value in zip(part["seeds"], part[name], strict=True):
                if seed in by_seed.setdefault(name, {}):
                    raise SystemExit(f"error: {name} seed {seed} is in more than one input")
                by_seed[name][seed] = value
        if part.get("ua2c_mean_executed_length"):  # empty when the part ran SAC only
            lengths = zip(part["seeds"], part["ua2c_mean_executed_length"], strict=True)
            by_seed.setdefault("ua2c_mean_executed_length", {}).update(lengths)
    seeds = sorted({s for values in by_seed.values() for s in values})
    missing = {name: [s for s in seeds if s not in values] for name, values in by_seed.items()}
    if any(missing.values()):
        raise SystemExit(f"error: seeds missing from the inputs: {missing}")
    record = {name: [values[s] for s in seeds] for name, values in by_seed.items()}
    record |= {"seeds": seeds, **{k: parts[0][k] for k in protocol},
               "ua2c_kwargs": with_ua2c[0][1]["ua2c_kwargs"] if with_ua2c else {}, "commands": [p["command"] for p in parts],
               "dates": [p["date"] for p in parts], "merged_by": shlex.join(["python", *sys.argv])}
    Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    Path(json_path).write_text(json.dumps(record, indent=1) + "\n")
    for name in ("ua2c", "sac"):
        if name in record:
            print(f"{name}: mean {np.mean(record[name]):.1f} over seeds {seeds}")


def _check_same(files: list[tuple[str, dict]], keys: tuple[str, ...]) -> None:
    """Exit with an error naming the file and keys where a part differs from the first of ``files``."""
    for f, part in files[1:]:
        differ = [k for k in keys if part[k] != files[0][1][k]]
        if differ:
            raise SystemExit(f"error: {f} differs from {files[0][0]} in {differ}: not the same protocol")


#: configurations of ``profile``: the defaults, the paper preset, the defaults before 2026-12-07 and one
#: speed lever each (on the defaults). The split follows the default bootstrap (Eq. 4's candidates):
#: ``critic_target="in_sample"`` is timed whole by ``throughput``, not here
PROFILE_CONFIGS: dict[str, dict] = {
    "defaults": {},
    "paper": preset("paper"),
    "2026-12-06 (3x512, N=10)": {"flow_steps": 10, "policy_kwargs": {"net_arch": [512, 512, 512]}},
    "field 128x2": {"policy_kwargs": {"net_arch": [128, 128]}},
    "N=2 acting": {"flow_steps": 2},
    "one-step actor": {"policy_kwargs": {"actor_type": "one_step"}},
    "MLP critic": {"policy_kwargs": {"critic_arch": "mlp"}},
    "fast 128": {"policy_kwargs": {"net_arch": [128, 128], "critic_arch": "mlp"}},
}


class _PartTimer:
    """Thread CPU ms per named part, summed over the parts' calls, medians over repetitions."""

    def __init__(self) -> None:
        self.current: dict[str, float] = {}
        self.rows: list[dict[str, float]] = []

    def part(self, name: str, fn: Callable[[], object]) -> object:
        start = time.thread_time()
        out = fn()
        self.current[name] = self.current.get(name, 0.0) + 1e3 * (time.thread_time() - start)
        return out

    def next_row(self) -> None:
        self.rows.append(self.current)
        self.current = {}

    def medians(self) -> dict[str, float]:
        return {name: statistics.median(row.get(name, 0.0) for row in self.rows) for name in self.rows[0]}


def _profiled_step(model: UA2C, data, timer: _PartTimer) -> None:
    """``UA2C._gradient_step`` cut into timed parts (the same calls in the same order)."""
    from stable_baselines3.common.utils import polyak_update

    from sb3_ua2c.chunking import bootstrap_value, chunk_critic_loss, chunk_target
    from sb3_ua2c.diagnostics import training_stats

    policy = model.policy
    obs_flat = data.observation_history.flatten(1)
    with th.no_grad():
        m = data.next_observation_history.shape[0]
        candidates = timer.part("target: candidates", lambda: policy.sample_chunks(
            data.next_observation_history, data.next_action_history, model.n_target_candidates,
            model.target_flow_steps))
        next_q = timer.part("target: critics", lambda: model.critic_target(
            data.next_observation_history.reshape(m, -1), candidates.clamp(-1.0, 1.0)))
        target = chunk_target(data.rewards, data.horizons, data.bootstrap, bootstrap_value(next_q), model.gamma)
    q = timer.part("critic: forward", lambda: model.critic(obs_flat, data.chunks.unsqueeze(1)).squeeze(2))
    critic_loss = chunk_critic_loss(q, target)
    model.critic.optimizer.zero_grad()
    timer.part("critic: backward", critic_loss.backward)
    timer.part("critic: Adam", model.critic.optimizer.step)
    loss, _ = timer.part("actor: forward (flow loss + value term)", lambda: model._actor_loss(data))
    model.actor.optimizer.zero_grad()
    timer.part("actor: backward", loss.backward)
    timer.part("actor: Adam", model.actor.optimizer.step)
    timer.part("Polyak", lambda: polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau))
    timer.part("logged stats", lambda: training_stats(model, data, q.detach(), target))
    timer.next_row()


def _profile_config(env_id: str, ua2c_kwargs: dict, repeats: int) -> dict[str, float]:
    """The parts of a gradient step and of a replanning of one configuration (thread CPU ms)."""
    model = UA2C("MlpPolicy", env_id, seed=0, **ua2c_kwargs)
    model.learn(model.learning_starts + 200)
    model.env.close()
    _skip_diagnostics_update(model, model._n_updates)  # the steps below call _gradient_step's parts directly
    model.policy.set_training_mode(True)
    timer = _PartTimer()
    for _ in range(repeats + 3):
        _profiled_step(model, model.replay_buffer.sample(model.batch_size), timer)
    timer.rows = timer.rows[3:]
    parts = timer.medians()
    step_flops = flops(lambda: model._gradient_step(model.replay_buffer.sample(model.batch_size)))
    model.policy.set_training_mode(False)
    policy, data = model.policy, model.replay_buffer.sample(1)
    obs_t, act_t = data.observation_history, data.action_history
    with th.inference_mode():
        plan = cpu_ms(lambda: policy.plan_tensors(obs_t, act_t), repeats * 10)
        plan_parts = _plan_parts(policy, obs_t, act_t, repeats * 10)
    row = {**parts, "gradient step (sum)": sum(parts.values()), "GFLOP": step_flops / 1e9, "replanning": plan,
           **{f"replanning: {k}": v for k, v in plan_parts.items()}}
    print({k: round(v, 2) for k, v in row.items()}, flush=True)
    return row


def profile(env_id: str, repeats: int, names: list[str]) -> None:
    """Where a gradient step and a replanning spend their time: each configuration of
    :data:`PROFILE_CONFIGS` after a warm-up on ``env_id`` (thread CPU ms, medians of ``repeats`` steps),
    next to SAC's gradient step and ``predict`` measured in the same run."""
    print(f"env {env_id}, thread CPU ms, medians of {repeats} steps")
    table = {name: _profile_config(env_id, PROFILE_CONFIGS[name], repeats) for name in names}
    sac = SAC("MlpPolicy", env_id, seed=0)
    sac.learn(sac.learning_starts + 200)
    obs = sac.env.reset()
    sac.env.close()
    sac_step = cpu_ms(lambda: sac.train(1, sac.batch_size), repeats, warmup=3)
    sac_predict = cpu_ms(lambda: sac.predict(obs, deterministic=True), repeats * 10)
    rows = list(next(iter(table.values())))
    print("\n| part | " + " | ".join(table) + " | SAC |")
    print("|---|" + "---|" * (len(table) + 1))
    for row in rows:
        sac_cell = {"gradient step (sum)": f"{sac_step:.2f}", "replanning": f"`predict` {sac_predict:.2f}"}.get(row, "")
        print(f"| {row} | " + " | ".join(f"{table[n][row]:.2f}" for n in table) + f" | {sac_cell} |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("part", choices=["latency", "throughput", "learning", "profile", "merge"])
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
    parser.add_argument("--configs", nargs="+", choices=list(PROFILE_CONFIGS), default=list(PROFILE_CONFIGS),
                        help="profile: the configurations to measure")
    parser.add_argument("--algos", nargs="+", choices=["UA2C", "SAC"], default=["UA2C", "SAC"])
    parser.add_argument("--json", default=None, help="learning, merge: write the per-seed returns to this JSON file")
    parser.add_argument("--inputs", nargs="+", default=[], help="merge: the learning --json files to merge")
    args = parser.parse_args()
    if args.part == "merge":
        if not args.inputs or not args.json:
            parser.error("merge needs --inputs FILE [FILE ...] and --json OUT")
        merge(args.inputs, args.json)
        return
    th.set_num_threads(1)
    print(f"torch {th.__version__}, {platform.processor() or platform.machine()}, 1 thread")
    if args.part == "latency":
        latency(args.repeats, args.ua2c_kwargs)
    elif args.part == "profile":
        profile(args.env, min(args.repeats, 30), args.configs)
    elif args.part == "throughput":
        throughput(args.steps or 1000, args.ua2c_kwargs, args.env)
    else:
        learning(args.steps or 20_000, args.seeds, args.eval_episodes, args.algos, args.ua2c_kwargs, args.json)


if __name__ == "__main__":
    main()
