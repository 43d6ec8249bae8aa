"""Training throughput when other processes share the cores, for torch's thread settings.

    python benchmarks/bench_threads.py                       # UA2C and SB3 SAC, threads default and 1, 0-2 loads
    python benchmarks/bench_threads.py --seconds 8 --loads 0 1

Each measurement is a fresh interpreter (torch's intra-op pool is sized once per process) that
fills a replay buffer on Pendulum-v1 and then times gradient steps (``model.train``) for about
``--seconds`` of wall time, while ``load`` other processes spin on the CPU (``while True: pass``).
Printed per algorithm and thread setting: gradient steps per wall second, and the ratio to the
same algorithm alone with the same setting and with torch's default. UA2C and SAC run side by side
under the same loads, so a collapse that only UA2C shows is UA2C's.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

CHILD = r"""
import json, sys, time
import torch as th
threads = int(sys.argv[2])
if threads > 0:
    th.set_num_threads(threads)
from stable_baselines3 import SAC
from sb3_ua2c import UA2C
algo, seconds = sys.argv[1], float(sys.argv[3])
cls = {"UA2C": UA2C, "SAC": SAC}[algo]
model = cls("MlpPolicy", "Pendulum-v1", learning_starts=400, seed=0, device="cpu", gradient_steps=0, train_freq=1)
model.learn(400)  # fills the buffer, no update
model.train(gradient_steps=5, batch_size=model.batch_size)  # warm-up
steps, start = 0, time.perf_counter()
while time.perf_counter() - start < seconds:
    model.train(gradient_steps=5, batch_size=model.batch_size)
    steps += 5
wall = time.perf_counter() - start
print(json.dumps({"steps_per_s": steps / wall, "threads": th.get_num_threads()}))
"""


def measure(algo: str, threads: int, load: int, seconds: float) -> dict:
    """Gradient steps per second of ``algo`` with ``threads`` (0: torch's default) next to ``load`` spinners."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        time.sleep(0.5 if load else 0.0)
        env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
        out = subprocess.run([sys.executable, "-c", CHILD, algo, str(threads), str(seconds)], env=env,
                             capture_output=True, text=True, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])
    finally:
        for p in spinners:
            p.kill()
            p.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=6.0, help="timed wall seconds per measurement")
    parser.add_argument("--loads", type=int, nargs="+", default=[0, 1, 2], help="other busy processes")
    parser.add_argument("--threads", type=int, nargs="+", default=[0, 1], help="torch threads (0: default)")
    parser.add_argument("--algos", nargs="+", default=["UA2C", "SAC"])
    args = parser.parse_args()
    if 0 not in args.loads:
        parser.error("--loads must include 0: the ratios are to the solo throughput")
    print(f"{os.cpu_count()} CPUs; {args.seconds:g} s per measurement; loads {args.loads}")
    rows = {}
    for load in args.loads:  # interleaved: every setting sees the machine in the same state
        for algo in args.algos:
            for threads in args.threads:
                rows[algo, threads, load] = measure(algo, threads, load, args.seconds)
    print(f"{'algo':>5} | {'threads':>8} | {'load':>4} | {'steps/s':>8} | {'/ solo':>7} | {'/ solo default':>14}")
    for (algo, threads, load), r in rows.items():
        solo, solo_default = rows[algo, threads, 0]["steps_per_s"], rows[algo, args.threads[0], 0]["steps_per_s"]
        label = f"{r['threads']}" + (" (dflt)" if threads == 0 else "")
        print(f"{algo:>5} | {label:>8} | {load:>4} | {r['steps_per_s']:8.1f} | {r['steps_per_s'] / solo:7.2f} | "
              f"{r['steps_per_s'] / solo_default:14.2f}")


if __name__ == "__main__":
    main()
