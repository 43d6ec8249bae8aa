"""rl-zoo integration benchmark: launcher overhead and Optuna sweeps on a shared journal file.

Runs, side by side in one run (the machine is shared, so only ratios measured together mean
something):

1. launcher overhead: ``python -m sb3_ua2c.zoo train --algo sac`` against rl-zoo3's own
   ``python -m rl_zoo3.train --algo sac`` with identical arguments (wall and CPU time per process,
   the two alternating);
2. sweep throughput: the same UA2C trials on Pendulum-v1 run by one worker with an in-memory study
   (rl-zoo3's default), one worker on a journal file and two workers sharing one journal file
   (rl-zoo3's ``--storage <dir>/study.log --study-name NAME``: Optuna's ``JournalStorage``).

The two workers run exactly the trials of the one-worker sweeps: those are drawn with one seed by
the random sampler, read back from the one-worker journal and enqueued in the shared study, from
which each worker takes its half. Nothing but Python and the ``zoo`` extra is needed.

Usage: ``python benchmarks/zoo_sweep.py [--trials 4] [--timesteps 200] [--repeats 2]``
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


def launcher_overhead(
    workdir: Path, repeats: int
) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """
    :return: (ours, peer): (wall, CPU) seconds of each process, in run order
    """
    common = ["--algo", "sac", "--env", "Pendulum-v1", "--conf-file", str(REPO / "zoo_configs" / "sac.yml"),
              "-n", "500", "--seed", "0", "--eval-freq", "-1", "--verbose", "0", "--num-threads", "1",
              "-params", "learning_starts:100", "batch_size:64"]  # fmt: skip
    ours, peer = [], []
    for i in range(repeats):  # alternate, so drifting machine load hits both alike
        peer.append(_run_all([[sys.executable, "-m", "rl_zoo3.train", *common, "-f", f"peer{i}"]], workdir))
        ours.append(
            _run_all([[sys.executable, "-m", "sb3_ua2c.zoo", "train", *common, "-f", f"ours{i}"]], workdir)
        )
    return ours, peer


def sweep_command(
    trials: int, timesteps: int, seed: int, folder: str, storage: Path | None, study: str | None
) -> list[str]:
    command = [sys.executable, "-m", "sb3_ua2c.zoo", "optimize", "--env", "Pendulum-v1",
               "--conf-file", str(REPO / "zoo_configs" / "ua2c.yml"), "--n-trials", str(trials),
               "--sampler", "random", "--pruner", "none", "-n", str(timesteps), "--n-evaluations", "1",
               "--eval-episodes", "1", "--env-kwargs", "max_episode_steps:100", "--no-optim-plots",
               "--num-threads", "1", "--seed", str(seed), "-f", folder, "--verbose", "0",
               # a few dozen gradient steps per trial (the sampler picks the network sizes)
               "-params", f"learning_starts:{max(timesteps - 50, 1)}", "buffer_size:10000"]  # fmt: skip
    if storage is not None:
        command += ["--storage", str(storage), "--study-name", study]
    return command


def journal(path: Path):
    """The Optuna storage rl-zoo3 opens for ``--storage path`` (a ``*.log`` file)."""
    import optuna

    return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(path)))


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
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")

    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="ua2c-zoo-bench-") as tmp:
        workdir = Path(tmp)
        print(f"cpus={os.cpu_count()} python={sys.version.split()[0]} optuna={optuna.__version__}")

        ours, peer = launcher_overhead(workdir, args.repeats)
        print(
            f"\n[launcher] SAC, Pendulum-v1, 500 steps, one process each, {args.repeats} alternating run(s)"
        )
        for i, ((o_wall, o_cpu), (p_wall, p_cpu)) in enumerate(zip(ours, peer, strict=True)):
            print(f"  run {i}: rl_zoo3.train (peer) wall {p_wall:7.2f} s cpu {p_cpu:7.2f} s | "
                  f"sb3_ua2c.zoo train wall {o_wall:7.2f} s cpu {o_cpu:7.2f} s | "
                  f"ours/peer wall {o_wall / p_wall:.2f} cpu {o_cpu / p_cpu:.2f}")  # fmt: skip
        wall = statistics.median(o[0] / p[0] for o, p in zip(ours, peer, strict=True))
        cpu = statistics.median(o[1] / p[1] for o, p in zip(ours, peer, strict=True))
        print(f"  median ratio ours/peer: wall {wall:.2f}, cpu {cpu:.2f}")

        n = args.trials
        memory, memory_cpu = _run_all([sweep_command(n, args.timesteps, 0, "mem", None, None)], workdir)
        one_log = workdir / "one" / "study.log"
        one, one_cpu = _run_all([sweep_command(n, args.timesteps, 0, "one", one_log, "bench-one")], workdir)
        done = optuna.load_study(study_name="bench-one", storage=journal(one_log)).trials
        two_log = workdir / "two" / "study.log"
        two_log.parent.mkdir()
        shared = optuna.create_study(study_name="bench-two", storage=journal(two_log), direction="maximize")
        for trial in done:
            shared.enqueue_trial(trial.params)
        two, two_cpu = _run_all(
            [
                sweep_command(n // 2, args.timesteps, seed, f"two{seed}", two_log, "bench-two")
                for seed in (1, 2)
            ],
            workdir,
        )
        ran = optuna.load_study(study_name="bench-two", storage=journal(two_log)).trials
        complete = sum(t.state == optuna.trial.TrialState.COMPLETE for t in ran)
        same = sorted(map(str, (t.params for t in done))) == sorted(map(str, (t.params for t in ran)))

        print(
            f"\n[sweep] UA2C, Pendulum-v1, {n} trials x {args.timesteps} steps, whole sweep (wall, CPU summed)"
        )
        print(f"  1 worker, in-memory study (peer)    wall {memory:7.2f} s   cpu {memory_cpu:7.2f} s")
        print(f"  1 worker, journal file              wall {one:7.2f} s   cpu {one_cpu:7.2f} s   "
              f"vs in-memory: wall {one / memory:.2f}, cpu {one_cpu / memory_cpu:.2f}")  # fmt: skip
        print(f"  2 workers, one shared journal file  wall {two:7.2f} s   cpu {two_cpu:7.2f} s   "
              f"vs in-memory: wall {two / memory:.2f} (speed-up {memory / two:.2f}x), "
              f"cpu {two_cpu / memory_cpu:.2f}")  # fmt: skip
        print(f"  shared study: {len(ran)} trials, {complete} complete, same trials as 1 worker: {same}")


if __name__ == "__main__":
    main()
