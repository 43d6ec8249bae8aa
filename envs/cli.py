"""Command line of the traffic job: ``python -m envs <command>`` (console script: ``ua2c``).

Commands, all on ``MixedTraffic-v0``: ``collect`` (offline dataset), ``pretrain`` (Phase 1),
``finetune`` (Phase 2), ``evaluate`` (metrics table + JSON), ``main`` (all four end to end),
``style`` (driving-style classifier: collect / train / evaluate). Each run writes into its own run
directory (``--run-dir``, default ``runs/<command>-<date>-<time>``). The research experiments
(Figure 2, the head-to-head, OGBench) run from a checkout as ``python -m experiments <command>``.

The algorithm package ``sb3_ua2c`` knows no traffic: this module drives its generic stages
(:func:`sb3_ua2c.pipeline.pretrain`, :func:`~sb3_ua2c.pipeline.finetune`) with the traffic
environment maker :func:`envs.collection.make_traffic_env`.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from envs.collection import (
    DRIVER_STYLES,
    TRAFFIC_DEFAULTS,
    BehaviourConfig,
    collect_dataset,
    make_traffic_env,
)
from envs.evaluation import episode_intervals, evaluate, format_table, plan_length_shares, summarize
from envs.style import main as style_main
from sb3_ua2c import UA2C
from sb3_ua2c.checks import check_int
from sb3_ua2c.cli_args import json_object_arg, threshold_arg
from sb3_ua2c.defaults import defaults
from sb3_ua2c.execution import format_length_shares
from sb3_ua2c.offline import load_dataset
from sb3_ua2c.pipeline import env_settings, finetune, pretrain, write_json

DEFAULT_RUNS = Path("runs")

#: Embedded defaults of ``main``: a few minutes on 2 cores.
MAIN_BUDGET = {
    "full": {"episodes": 200, "pretrain_steps": 3000, "finetune_steps": 6000, "eval_episodes": 30},
    "quick": {"episodes": 4, "pretrain_steps": 30, "finetune_steps": 200, "eval_episodes": 1},
}


def _run_dir(args: argparse.Namespace) -> Path:
    if args.run_dir is not None:
        path = Path(args.run_dir)
    else:
        path = DEFAULT_RUNS / f"{args.command}-{time.strftime('%Y%m%d-%H%M%S')}"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _behaviour(args: argparse.Namespace) -> BehaviourConfig:
    return BehaviourConfig(
        sumo_fraction=args.sumo_fraction, perturb_prob=args.perturb_prob, accel_noise=args.accel_noise,
        perturb_steps=args.perturb_steps, lane_change_prob=args.lane_change_prob, driver_style=args.driver_style,
    )


def _settings_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The ``make_traffic_env`` arguments: the dataset's (``--dataset``), else ``--env-kwargs`` /
    ``--style-classifier``."""
    if getattr(args, "dataset", None):
        return env_settings(load_dataset(args.dataset))
    return {"env_id": "MixedTraffic-v0", "env_kwargs": args.env_kwargs, "style_classifier": args.style_classifier}


def cmd_collect(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else _run_dir(args) / "dataset"
    ds = collect_dataset(
        out, args.episodes, env_kwargs=args.env_kwargs, style_classifier=args.style_classifier,
        behaviour=_behaviour(args), seed=args.seed, progress_bar=not args.no_progress, overwrite=args.overwrite,
    )
    print(f"dataset: {out} ({len(ds)} episodes, {ds.total_steps} steps, mean return {ds.metadata['mean_return']:.2f})")
    return 0


def cmd_pretrain(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else _run_dir(args) / "pretrained.zip"
    path = pretrain(
        args.dataset, out, args.steps, seed=args.seed, algo_kwargs={**TRAFFIC_DEFAULTS, **(args.hyperparams or {})},
        progress_bar=not args.no_progress, verbose=args.verbose, make_env=make_traffic_env,
    )
    print(f"checkpoint: {path}")
    return 0


def cmd_finetune(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else _run_dir(args) / "finetuned.zip"
    path = finetune(
        args.checkpoint, out, args.timesteps, dataset=args.dataset,
        env_settings_=_settings_from_args(args), offline_ratio=args.offline_ratio,
        entropy_threshold=args.entropy_threshold, seed=args.seed, progress_bar=not args.no_progress,
        monitor_file=out.with_suffix(""), make_env=make_traffic_env,
    )
    print(f"checkpoint: {path}; online episodes: {out.with_suffix('')}.monitor.csv")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    settings = _settings_from_args(args)
    rows, raw = {}, {}
    for ckpt in args.checkpoint:
        results = evaluate(
            ckpt, n_episodes=args.episodes, seeds=tuple(args.seeds), env_settings_=settings,
            entropy_threshold=args.entropy_threshold, deterministic=not args.stochastic,
        )
        rows[Path(ckpt).stem] = summarize(results)
        raw[str(ckpt)] = results
    print(format_table(rows))
    out = Path(args.json) if args.json else _run_dir(args) / "evaluation.json"
    write_json(out, {"summary": rows, "episodes": raw, "seeds": args.seeds, "episodes_per_seed": args.episodes})
    print(f"results: {out}")
    return 0


def _evaluate_for_main(checkpoint: str, n_episodes: int, seed: int, settings: dict[str, Any]) -> list[Any]:
    """``main``'s evaluation of one checkpoint on its held-out scenarios, one torch thread (it may run in
    a second process beside the fine-tuning: libsumo runs one simulation per process)."""
    import torch

    torch.set_num_threads(1)
    return evaluate(UA2C.load(checkpoint, device="cpu"), n_episodes=n_episodes, seeds=(seed,), env_settings_=settings)


def cmd_main(args: argparse.Namespace) -> int:
    """collect -> pretrain -> finetune -> evaluate with :data:`MAIN_BUDGET`; prints the metrics table with
    the 95 % intervals over the evaluation episodes and the ``L_t`` histogram of each checkpoint, and
    writes ``summary.json`` into the run directory. The pre-trained checkpoint is evaluated in a second
    process while the fine-tuning runs (each on one torch thread: the job uses two cores)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import torch

    budget = MAIN_BUDGET["quick" if args.quick else "full"]
    run = _run_dir(args)
    progress = not args.no_progress
    if args.threads == 0:
        torch.set_num_threads(1)
    t0 = time.time()
    print(f"[1/4] collect {budget['episodes']} episodes of SUMO-driven data -> {run / 'dataset'}"
          f"{'' if args.no_style_context else ' (with the driving-style context c_t)'}")
    style_classifier = None if args.no_style_context else "default"
    ds = collect_dataset(
        run / "dataset", budget["episodes"], seed=args.seed, style_classifier=style_classifier, progress_bar=progress,
        overwrite=True,
    )
    settings = env_settings(ds)
    print(f"[2/4] Phase 1: pre-train UA2C for {budget['pretrain_steps']} gradient steps")
    pre = pretrain(ds, run / "pretrained.zip", budget["pretrain_steps"], seed=args.seed, progress_bar=progress,
                   algo_kwargs=TRAFFIC_DEFAULTS, make_env=make_traffic_env)
    eval_args = (budget["eval_episodes"], args.seed + 100, settings)
    print(f"[3/4] Phase 2: online adaptation for {budget['finetune_steps']} env steps (adaptive chunks); "
          f"meanwhile the pre-trained checkpoint is evaluated on {budget['eval_episodes']} held-out scenarios")
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = pool.submit(_evaluate_for_main, str(pre), *eval_args)
        fine = finetune(
            pre, run / "finetuned.zip", budget["finetune_steps"], dataset=ds, seed=args.seed, progress_bar=progress,
            monitor_file=run / "finetuned",  # SB3's Monitor log of the online episodes: finetuned.monitor.csv
            make_env=make_traffic_env,
        )
        print(f"[4/4] evaluate the fine-tuned checkpoint on the same {budget['eval_episodes']} scenarios")
        raw = {"finetuned": _evaluate_for_main(str(fine), *eval_args), "pretrained": pending.result()}
    raw = {name: raw[name] for name in ("pretrained", "finetuned")}
    rows = {name: summarize(results) for name, results in raw.items()}
    rows["dataset"] = {
        "reward": ds.metadata["mean_return"], "cumulative_jerk": math.nan, "collision": math.nan,
        "merge_success": math.nan, "mean_speed": math.nan, "mean_executed_length": math.nan,
    }
    print(format_table(rows, {name: episode_intervals(results) for name, results in raw.items()}))
    k = {**defaults(), **TRAFFIC_DEFAULTS}["chunk_size"]
    for name, results in raw.items():
        print(f"{name:>11} | L_t = 1..{k}, % of plans: {format_length_shares(plan_length_shares(results, k))}")
    write_json(run / "summary.json", {"summary": rows, "episodes": raw, "budget": budget, "seconds": time.time() - t0})
    print(f"run directory: {run}  ({time.time() - t0:.0f} s)")
    return 0


def _common_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run-dir", default=None, help="output directory (default: runs/<command>-<date>-<time>)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--threads", type=int, default=0,
                   help="torch CPU threads (default 0: torch's default; 1 is faster on a busy machine, where "
                        "more threads spin-wait)")


def _env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--env-kwargs", type=json_object_arg, default={}, help="MixedTraffic-v0 keyword arguments as JSON")
    p.add_argument("--style-classifier", default=None,
                   help="append the driving-style context c_t (Eq. 6): a classifier path or 'default'")


def _add_collect(sub: Any) -> None:
    p = sub.add_parser("collect", help="collect an offline dataset (local Minari) with a human-like behaviour policy")
    _common_args(p)
    _env_args(p)
    p.add_argument("--out", default=None, help="dataset directory (default: <run-dir>/dataset)")
    p.add_argument("--episodes", type=int, default=100)
    b = BehaviourConfig()  # the behaviour defaults live in one place
    p.add_argument("--sumo-fraction", type=float, default=b.sumo_fraction,
                   help="fraction of episodes driven by SUMO's model")
    p.add_argument("--perturb-prob", type=float, default=b.perturb_prob,
                   help="per-step probability that a takeover starts in SUMO episodes")
    p.add_argument("--accel-noise", type=float, default=b.accel_noise,
                   help="std of a takeover's acceleration offset [m/s^2]")
    p.add_argument("--perturb-steps", type=int, default=b.perturb_steps, help="length of a takeover [steps]")
    p.add_argument("--lane-change-prob", type=float, default=b.lane_change_prob,
                   help="per-step random lane-change probability")
    p.add_argument("--driver-style", default=b.driver_style, choices=DRIVER_STYLES,
                   help="SUMO driver parameters of the AV ('mixed': one style drawn per episode)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_collect)


def _add_pretrain(sub: Any) -> None:
    p = sub.add_parser("pretrain", help="Phase 1: pre-train UA2C from a dataset")
    _common_args(p)
    p.add_argument("--dataset", required=True, help="dataset directory")
    p.add_argument("--out", default=None, help="checkpoint (default: <run-dir>/pretrained.zip)")
    p.add_argument("--steps", type=int, default=20_000, help="gradient steps")
    p.add_argument("--hyperparams", type=json_object_arg, default={},
                   help='UA2C arguments as JSON, e.g. \'{"chunk_size": 1}\' for the one-step baseline')
    p.add_argument("--verbose", type=int, default=0)
    p.set_defaults(func=cmd_pretrain)


def _add_finetune(sub: Any) -> None:
    p = sub.add_parser("finetune", help="Phase 2: online adaptation from a pre-trained checkpoint")
    _common_args(p)
    _env_args(p)
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--dataset", default=None, help="offline data kept in the replay buffer (also defines the env)")
    p.add_argument("--out", default=None, help="checkpoint (default: <run-dir>/finetuned.zip)")
    p.add_argument("--timesteps", type=int, default=50_000)
    p.add_argument("--offline-ratio", type=float, default=None)
    p.add_argument("--entropy-threshold", type=threshold_arg, default=None,
                   help="δ of Eq. 7; 'inf' = fixed chunks; 'auto' = set from recent plans")
    p.set_defaults(func=cmd_finetune)


def _add_evaluate(sub: Any) -> None:
    p = sub.add_parser("evaluate", help="evaluate checkpoints: reward, jerk, collisions, merges, mean L_t")
    _common_args(p)
    _env_args(p)
    p.add_argument("--checkpoint", required=True, nargs="+")
    p.add_argument("--dataset", default=None, help="take the env configuration from this dataset")
    p.add_argument("--episodes", type=int, default=10, help="episodes per seed")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--entropy-threshold", type=threshold_arg, default=None,
                   help="δ of Eq. 7 to act with; 'inf' = fixed chunks; 'auto' = the checkpoint's window")
    p.add_argument("--stochastic", action="store_true", help="fresh candidate noise at every plan")
    p.add_argument("--json", default=None, help="results file (default: <run-dir>/evaluation.json)")
    p.set_defaults(func=cmd_evaluate)


def _add_main(sub: Any) -> None:
    p = sub.add_parser("main", help="collect -> pretrain -> finetune -> evaluate, end to end with embedded defaults")
    _common_args(p)
    p.add_argument("--quick", action="store_true", help="a tiny budget (seconds), for smoke tests")
    p.add_argument("--no-style-context", action="store_true",
                   help="train on the raw 20-number observation (no driving-style context c_t)")
    p.set_defaults(func=cmd_main)


def build_parser(prog: str = "ua2c") -> argparse.ArgumentParser:
    """The parser of every command but ``style`` (which :func:`main` hands to :func:`envs.style.main`).

    :param prog: the program name in the usage line
    """
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_collect, _add_pretrain, _add_finetune, _add_evaluate, _add_main):
        add(sub)
    sub.add_parser("style", help="driving-style classifier: collect / train / evaluate (see 'style --help')",
                   add_help=False)
    return parser


def _set_threads(threads: int) -> None:
    check_int("--threads", threads, low=0)
    if threads > 0:
        import torch

        torch.set_num_threads(threads)


def main(argv: list[str] | None = None, prog: str = "ua2c") -> int:
    """Run one command; return its exit code (2 on bad input, with the reason on stderr).

    :param argv: the arguments (default ``sys.argv[1:]``)
    :param prog: the program name in the usage line (``ua2c``, or ``python -m envs``)
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "style":
        return int(style_main(argv[1:]) or 0)
    args = build_parser(prog).parse_args(argv)
    try:
        _set_threads(args.threads)
        return args.func(args)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
