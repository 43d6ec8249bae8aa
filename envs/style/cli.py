"""Command line of the style module: ``python -m envs style collect|train|evaluate`` (also
reachable as ``python -m envs.style``)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from envs.style.data import StyleDataset, collect_style_dataset
from envs.style.metrics import format_confusion, plot_confusion
from envs.style.model import DrivingStyleClassifier
from envs.style.sequences import STYLES
from envs.style.train import evaluate_style_classifier, train_style_classifier


def _parse_kv(pairs: Sequence[str] | None) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}`` (values parsed as JSON when possible)."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise ValueError(f"expected key=value, got {pair!r}")
        key, value = pair.split("=", 1)
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``python -m envs.style`` (subcommands collect, train, evaluate)."""
    parser = argparse.ArgumentParser(
        prog="python -m envs.style",
        description="Driving-style inference (UA2C Eq. 5): collect a labelled dataset from "
        "MixedTraffic-v0, train the Transformer classifier, evaluate it against a baseline.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    fmt = argparse.ArgumentDefaultsHelpFormatter
    c = sub.add_parser(
        "collect",
        formatter_class=fmt,
        help="roll out the environment and save labelled slot sequences (.npz)",
    )
    c.add_argument("--episodes", type=int, default=1500, help="number of episodes")
    c.add_argument("--out", default="style_data.npz", help="output .npz file")
    c.add_argument("--env", default="MixedTraffic-v0", help="gymnasium id")
    c.add_argument("--seq-len", type=int, default=20, help="tokens per slot sequence ℓ")
    c.add_argument("--stride", type=int, default=5, help="sample every N steps")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--max-steps", type=int, default=None, help="cut episodes after this many steps")
    c.add_argument(
        "--sumo-driver-fraction",
        type=float,
        default=0.5,
        help="share of episodes where SUMO drives the AV (the rest: random driver)",
    )
    c.add_argument("--env-kwargs", nargs="*", metavar="KEY=VALUE", help="gym.make keyword arguments")
    c.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    t = sub.add_parser(
        "train", formatter_class=fmt, help="train the classifier with early stopping (split by episode)"
    )
    t.add_argument("--data", required=True, help=".npz written by collect")
    t.add_argument("--out", default="style_classifier.pt", help="output weights file")
    t.add_argument("--model", nargs="*", metavar="KEY=VALUE", help="StyleClassifierConfig fields")
    t.add_argument("--train", nargs="*", metavar="KEY=VALUE", help="StyleTrainConfig fields")
    t.add_argument("--no-progress", action="store_true")
    e = sub.add_parser(
        "evaluate", formatter_class=fmt, help="evaluate on the held-out episodes, with the baseline"
    )
    e.add_argument("--data", required=True, help=".npz written by collect")
    e.add_argument("--model", required=True, help="weights file written by train")
    e.add_argument("--json", default="results/style_eval.json", help="metrics output")
    e.add_argument("--png", default="results/style_confusion.png", help="confusion matrix figure")
    e.add_argument("--no-baseline", action="store_true", help="skip the logistic-regression baseline")
    return parser


def _collect(args: argparse.Namespace) -> None:
    ds = collect_style_dataset(
        args.episodes,
        env_id=args.env,
        seq_len=args.seq_len,
        stride=args.stride,
        seed=args.seed,
        env_kwargs=_parse_kv(args.env_kwargs),
        max_steps_per_episode=args.max_steps,
        sumo_driver_fraction=args.sumo_driver_fraction,
        progress_bar=not args.no_progress,
    )
    ds.save(args.out)
    counts = np.bincount(ds.labels, minlength=len(STYLES))
    print(
        f"saved {len(ds)} samples from {args.episodes} episodes to {args.out}; "
        f"per style: {dict(zip(STYLES, counts.tolist(), strict=False))}"
    )


def _train(args: argparse.Namespace) -> None:
    ds = StyleDataset.load(args.data)
    model, hist = train_style_classifier(
        ds, _parse_kv(args.model), _parse_kv(args.train), progress_bar=not args.no_progress
    )
    model.save(args.out)
    print(
        f"best epoch {hist['best_epoch']} (val loss {hist['best_val_loss']:.4f}, "
        f"val macro acc {hist['val_accuracy'][hist['best_epoch']]:.3f}) in {hist['seconds']:.1f}s; "
        f"saved to {args.out}"
    )


def _evaluate(args: argparse.Namespace) -> None:
    ds = StyleDataset.load(args.data)
    model = DrivingStyleClassifier.load(args.model)
    res = evaluate_style_classifier(model, ds, baseline=not args.no_baseline)
    print(format_confusion(np.asarray(res["confusion_matrix"]), res["classes"]))
    print(
        f"transformer: macro accuracy {res['macro_accuracy']:.3f}, accuracy {res['accuracy']:.3f} "
        f"(n={res['n']})"
    )
    for name, pc in res["per_class"].items():
        print(f"  {name:>12}: precision {pc['precision']:.3f} recall {pc['recall']:.3f} (n={pc['support']})")
    if "baseline" in res:
        print(
            f"baseline (logistic regression): macro accuracy {res['baseline']['macro_accuracy']:.3f}, "
            f"accuracy {res['baseline']['accuracy']:.3f}"
        )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    plot_confusion(
        np.asarray(res["confusion_matrix"]),
        args.png,
        res["classes"],
        title=f"driving style, macro acc {res['macro_accuracy']:.3f}",
    )
    print(f"wrote {args.json} and {args.png}")


_COMMANDS = {"collect": _collect, "train": _train, "evaluate": _evaluate}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m envs style`` / ``python -m envs.style``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        _COMMANDS[args.command](args)
    except ValueError as err:
        parser.error(str(err))
    return 0
