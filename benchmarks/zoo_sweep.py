"""rl-zoo integration benchmark: launcher overhead and multi-worker Optuna sweeps on PostgreSQL.

Runs, side by side in one run (the machine is shared, so only ratios measured together mean
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
import resource
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


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run_all(commands: list[list[str]], cwd: Path) -> tuple[float, float]:
    """
    Start all commands at once and wait for all.

    :return: (wall time, CPU time summed over the processes) in seconds
    :raises RuntimeError: when a process fails
    """
    cpu = _children_cpu()
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
    return elapsed, _children_cpu() - cpu


def launcher_overhead(workdir: Path, repeats: int) -> tuple[tuple[float, float], tuple[float, float]]:
    common = ["--algo", "sac", "--env", "Pendulum-v1", "--conf-file", str(REPO / "zoo_configs" / "sac.yml"),
              "-n", "500", "--seed", "0", "--eval-freq", "-1", "--verbose", "0", "--num-threads", "1",
              "-params", "learning_starts:100", "batch_size:64"]  # fmt: skip
    ours, peer = [], []
    for i in range(repeats):  # alternate, so drifting machine load hits both alike
        peer.append(_run_all([[sys.executable, "-m", "rl_zoo3.train", *common, "-f", f"peer{i}"]], workdir))
        ours.append(
            _run_all([[sys.executable, "-m", "sb3_ua2c.zoo", "train", *common, "-f", f"ours{i}"]], workdir)
        )

    def median(runs: list[tuple[float, float]]) -> tuple[float, float]:
        return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)

    return median(ours), median(peer)


def sweep_command(trials: int, timesteps: int, seed: int, folder: str, storage: str | None) -> list[str]:
    command = [sys.executable, "-m", "sb3_ua2c.zoo", "optimize", "--env", "Pendulum-v1",
               "--conf-file", str(REPO / "zoo_configs" / "ua2c.yml"), "--n-trials", str(trials),
               "--sampler", "random", "--pruner", "none", "-n", str(timesteps), "--n-evaluations", "1",
               "--eval-episodes", "1", "--env-kwargs", "max_episode_steps:100", "--no-optim-plots",
               "--num-threads", "1", "--seed", str(seed), "-f", folder, "--verbose", "0",
               # a few dozen gradient steps per trial (the sampler picks the network sizes)
               "-params", f"learning_starts:{max(timesteps - 50, 1)}", "buffer_size:10000"]  # fmt: skip
    if storage is not None:
        command += ["--storage", storage, "--study-name", f"bench-{folder}"]
    return command


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--trials", type=int, default=4, help="trials per sweep (even: split over 2 workers)")
    parser.add_argument("--timesteps", type=int, default=200, help="training steps per trial (last 50 learn)")
    parser.add_argument("--repeats", type=int, default=2, help="repeats of the launcher-overhead runs")
    args = parser.parse_args()
    if args.trials < 2 or args.trials % 2:
        parser.error("--trials must be an even number >= 2")

    with tempfile.TemporaryDirectory(prefix="ua2c-zoo-bench-") as tmp, PostgresServer() as server:
        workdir = Path(tmp)
        print(f"cpus={os.cpu_count()} python={sys.version.split()[0]}")

        (ours, ours_cpu), (peer, peer_cpu) = launcher_overhead(workdir, args.repeats)
        print("\n[launcher] SAC, Pendulum-v1, 500 steps, one process, median of the runs")
        print(f"  rl_zoo3.train (peer)   wall {peer:7.2f} s   cpu {peer_cpu:7.2f} s")
        print(f"  sb3_ua2c.zoo train     wall {ours:7.2f} s   cpu {ours_cpu:7.2f} s   "
              f"ratio ours/peer: wall {ours / peer:.2f}, cpu {ours_cpu / peer_cpu:.2f}")  # fmt: skip

        n = args.trials
        memory, memory_cpu = _run_all([sweep_command(n, args.timesteps, 0, "mem", None)], workdir)
        pg_one, pg_one_cpu = _run_all(
            [sweep_command(n, args.timesteps, 0, "pg1", server.create_database("one"))], workdir
        )
        # The two workers run exactly the trials of the one-worker sweeps (same seed, same draws):
        # they pop them from the shared study's queue.
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        done = optuna.load_study(study_name="bench-pg1", storage=server.url("one")).trials
        url = server.create_database("two")
        shared = optuna.create_study(study_name="bench-pg2", storage=url, direction="maximize")
        for trial in done:
            shared.enqueue_trial(trial.params)
        pg_two, pg_two_cpu = _run_all(
            [sweep_command(n // 2, args.timesteps, seed, "pg2", url) for seed in (1, 2)], workdir
        )
        print(f"\n[sweep] UA2C, Pendulum-v1, {n} trials x {args.timesteps} steps, whole sweep")
        print(f"  1 worker, in-memory study (peer)  wall {memory:7.2f} s   cpu {memory_cpu:7.2f} s")
        print(f"  1 worker, PostgreSQL (same trials) wall {pg_one:7.2f} s   cpu {pg_one_cpu:7.2f} s   "
              f"cpu ratio vs in-memory = {pg_one_cpu / memory_cpu:.2f}")  # fmt: skip
        same = sorted(map(str, (t.params for t in done))) == sorted(
            map(str, (t.params for t in optuna.load_study(study_name="bench-pg2", storage=url).trials))
        )
        print(f"  2 workers, shared PostgreSQL (same trials: {same})")
        print(f"                                    wall {pg_two:7.2f} s   cpu {pg_two_cpu:7.2f} s   "
              f"wall speed-up vs 1 worker in-memory = {memory / pg_two:.2f}x")  # fmt: skip


if __name__ == "__main__":
    main()
