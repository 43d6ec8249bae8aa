"""rl-zoo integration benchmark: launcher overhead and multi-worker Optuna sweeps on PostgreSQL.

Runs, side by side in one session (the machine is shared, so only ratios measured together mean
something):

1. launcher overhead: ``python -m sb3_ua2c.zoo train --algo sac`` against rl-zoo3's own
   ``python -m rl_zoo3.train --algo sac`` with identical arguments (wall time of the process);
2. sweep throughput: the same number of UA2C trials on Pendulum-v1 run by one worker with an
   in-memory study, one worker on PostgreSQL, and two workers sharing a PostgreSQL study.

The PostgreSQL server is a throw-away one on loopback (as in ``tests/test_zoo_postgres.py``);
the benchmark needs the Debian ``postgresql`` package.

Usage: ``python benchmarks/zoo_sweep.py [--trials 6] [--timesteps 300] [--repeats 2]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from postgres_server import PostgresServer  # noqa: E402

ENV = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")


def _run_all(commands: list[list[str]], cwd: Path) -> float:
    """Start all commands at once, wait for all; wall time in seconds. Raises on a failed process."""
    start = time.perf_counter()
    procs = [
        subprocess.Popen(c, cwd=cwd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for c in commands
    ]
    outputs = [p.communicate()[0] for p in procs]
    elapsed = time.perf_counter() - start
    for proc, out in zip(procs, outputs, strict=True):
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(proc.args)} failed:\n{out[-3000:]}")
    return elapsed


def launcher_overhead(workdir: Path, repeats: int) -> tuple[float, float]:
    common = ["--algo", "sac", "--env", "Pendulum-v1", "--conf-file", str(REPO / "zoo_configs" / "sac.yml"),
              "-n", "500", "--seed", "0", "--eval-freq", "-1", "--verbose", "0", "--num-threads", "1",
              "-params", "learning_starts:100", "batch_size:64"]  # fmt: skip
    ours, peer = [], []
    for i in range(repeats):  # alternate, so drifting machine load hits both alike
        peer.append(_run_all([[sys.executable, "-m", "rl_zoo3.train", *common, "-f", f"peer{i}"]], workdir))
        ours.append(_run_all([[sys.executable, "-m", "sb3_ua2c.zoo", "train", *common, "-f", f"ours{i}"]], workdir))
    return statistics.median(ours), statistics.median(peer)


def sweep_command(trials: int, timesteps: int, seed: int, folder: str, storage: str | None) -> list[str]:
    command = [sys.executable, "-m", "sb3_ua2c.zoo", "optimize", "--env", "Pendulum-v1",
               "--conf-file", str(REPO / "zoo_configs" / "ua2c.yml"), "--n-trials", str(trials),
               "--sampler", "random", "--pruner", "none", "-n", str(timesteps), "--n-evaluations", "1",
               "--eval-episodes", "1", "--env-kwargs", "max_episode_steps:100", "--no-optim-plots",
               "--num-threads", "1", "--seed", str(seed), "-f", folder, "--verbose", "0",
               # small networks and learning after 100 steps: trials of about a second or two
               "-params", "learning_starts:100", "buffer_size:10000"]  # fmt: skip
    if storage is not None:
        command += ["--storage", storage, "--study-name", f"bench-{folder}"]
    return command


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=6, help="trials per sweep (even: split over 2 workers)")
    parser.add_argument("--timesteps", type=int, default=300, help="training steps per trial")
    parser.add_argument("--repeats", type=int, default=2, help="repeats of the launcher-overhead runs")
    args = parser.parse_args()
    if args.trials < 2 or args.trials % 2:
        parser.error("--trials must be an even number >= 2")

    with tempfile.TemporaryDirectory(prefix="ua2c-zoo-bench-") as tmp, PostgresServer() as server:
        workdir = Path(tmp)
        print(f"cpus={os.cpu_count()} python={sys.version.split()[0]}")

        ours, peer = launcher_overhead(workdir, args.repeats)
        print("\n[launcher] SAC, Pendulum-v1, 500 steps, one process, median wall time")
        print(f"  rl_zoo3.train (peer)   {peer:7.2f} s")
        print(f"  sb3_ua2c.zoo train     {ours:7.2f} s   ratio ours/peer = {ours / peer:.2f}")

        n = args.trials
        memory = _run_all([sweep_command(n, args.timesteps, 0, "mem", None)], workdir)
        pg_one = _run_all([sweep_command(n, args.timesteps, 0, "pg1", server.create_database("one"))], workdir)
        url = server.create_database("two")
        pg_two = _run_all(
            [sweep_command(n // 2, args.timesteps, seed, "pg2", url) for seed in (1, 2)], workdir
        )
        print(f"\n[sweep] UA2C, Pendulum-v1, {n} trials x {args.timesteps} steps, wall time of the whole sweep")
        print(f"  1 worker, in-memory study (peer)  {memory:7.2f} s   {60 * n / memory:5.1f} trials/min")
        print(f"  1 worker, PostgreSQL              {pg_one:7.2f} s   ratio vs in-memory = {pg_one / memory:.2f}")
        print(f"  2 workers, shared PostgreSQL      {pg_two:7.2f} s   speed-up vs 1 worker in-memory = "
              f"{memory / pg_two:.2f}x")  # fmt: skip


if __name__ == "__main__":
    main()
