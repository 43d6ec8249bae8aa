"""The paired per-seed difference of any two arms, within one run or across two runs (``docs/peers.md``):
``python -m experiments paired X Y``, each side ``RAW_DIR:ARM`` (a head-to-head's records) or
``FILE.json:KEY.KEY...`` (a per-seed list in a report, paired with the nearest ``seeds`` list)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common.stats import LOWER_IS_BETTER, interval, paired_difference, run_scores
from experiments.peers.runner import PeersPaths, load_records


@dataclass(frozen=True)
class SeedScores:
    """One score per seed of one arm, and what must match for two arms to be paired."""

    name: str
    scores: dict[int, float]  # seed -> score of that run
    conditions: dict[int, Any]  # seed -> (dataset seed, evaluation seeds); empty when the source has none


def raw_scores(raw: Path, arm: str, metric: str, evaluation: str) -> SeedScores:
    """One score per run of ``arm`` (or of a peer's ``<peer>_best_of_n`` row) among the records under ``raw``."""
    records = load_records(PeersPaths(raw.parent, raw, raw.parent))
    base = arm.removesuffix("_best_of_n")
    if arm not in records and base in records:  # the peer ran, but was not evaluated by best of N
        raise ValueError(f"{base!r} under {raw} has no 'evaluation_best_of_n'")
    if arm not in records:
        raise ValueError(f"no records of arm {arm!r} under {raw}; arms there: {sorted(records)}")
    runs = sorted(records[arm], key=lambda r: r["seed"])  # run_scores' order
    for record in runs:
        if not record.get(evaluation):
            raise ValueError(f"seed {record['seed']} of {arm!r} has no {evaluation!r}"
                             + (" (an online-only arm has no offline evaluation)"
                                if evaluation == "offline_evaluation" else ""))
    scores = run_scores(runs, metric, evaluation)  # (n_runs,)
    return SeedScores(f"{raw}:{arm}", {r["seed"]: float(v) for r, v in zip(runs, scores, strict=True)},
                      {r["seed"]: (r["dataset"].get("seed"), tuple(r["eval_seeds"])) for r in runs})


def json_scores(path: Path, keys: Sequence[str]) -> SeedScores:
    """The per-seed list at ``keys`` inside the JSON file ``path``, with the nearest ``seeds`` list."""
    node: Any = json.loads(path.read_text())
    seeds = node.get("seeds") if isinstance(node, Mapping) else None
    for i, key in enumerate(keys):
        if not isinstance(node, Mapping) or key not in node:
            options = sorted(node) if isinstance(node, Mapping) else type(node).__name__
            raise ValueError(f"{path}: no key {key!r} at {'.'.join(keys[:i]) or 'the top level'}; there: {options}")
        seeds = node.get("seeds", seeds)
        node = node[key]
    if not isinstance(node, list) or not all(isinstance(v, (int, float)) for v in node):
        raise ValueError(f"{path}:{'.'.join(keys)} is not a list of numbers")
    if not isinstance(seeds, list) or len(seeds) != len(node):
        raise ValueError(f"{path}:{'.'.join(keys)} has {len(node)} scores but the nearest 'seeds' is {seeds!r}")
    return SeedScores(f"{path}:{'.'.join(keys)}", {int(s): float(v) for s, v in zip(seeds, node, strict=True)}, {})


def load_scores(spec: str, metric: str, evaluation: str) -> SeedScores:
    """:func:`raw_scores` or :func:`json_scores`, from ``RAW_DIR:ARM`` or ``FILE.json:KEY.KEY...``."""
    where, sep, what = spec.rpartition(":")
    if not sep or not where or not what:
        raise ValueError(f"{spec!r}: expected RAW_DIR:ARM or FILE.json:KEY.KEY...")
    path = Path(where)
    if path.suffix == ".json":
        if not path.is_file():
            raise ValueError(f"{spec!r}: no file {path}")
        return json_scores(path, what.split("."))
    if not path.is_dir():
        raise ValueError(f"{spec!r}: no directory {path}")
    return raw_scores(path, what, metric, evaluation)


def pair(x: SeedScores, y: SeedScores, higher_is_better: bool = True) -> dict[str, Any]:
    """Both arms' means over their shared seeds and :func:`paired_difference` (positive: X does better)."""
    shared = sorted(set(x.scores) & set(y.scores))
    if len(shared) < 2:
        raise ValueError(f"{x.name} and {y.name} share {len(shared)} seed(s); a paired interval needs 2")
    if x.conditions and y.conditions:
        differ = [s for s in shared if x.conditions[s] != y.conditions[s]]
        if differ:
            raise ValueError(f"not paired: on seed(s) {differ} the two runs used different datasets or "
                             f"evaluation scenarios ({x.conditions[differ[0]]} vs {y.conditions[differ[0]]})")
    sx, sy = (np.array([side.scores[s] for s in shared]) for side in (x, y))  # (n_shared,) each
    return {"seeds": shared, "x_mean": float(sx.mean()), "y_mean": float(sy.mean()),
            **paired_difference(sx, sy, higher_is_better=higher_is_better)}


def format_pair(x: SeedScores, y: SeedScores, result: Mapping[str, Any], metric: str,
                higher_is_better: bool = True) -> str:
    """X's and Y's means over the shared seeds, then their paired difference, saying which way is better."""
    if not (x.conditions and y.conditions):  # a report's list: its metric is whatever the list holds
        metric = "score"
    if not higher_is_better:
        sense, ahead = "Y − X (lower is better), X better when > 0", "X ahead in"
    elif metric in LOWER_IS_BETTER:
        sense, ahead = "X − Y (a cost: X better when < 0; --lower-is-better reports Y − X)", "X higher in"
    else:
        sense, ahead = "X − Y, X better when > 0", "X ahead in"
    return (f"X = {x.name}: {result['x_mean']:.2f}\nY = {y.name}: {result['y_mean']:.2f}\n"
            f"{metric}, {sense}, paired over seeds {result['seeds']}: {interval(result)} (95 % Student-t); "
            f"{ahead} {result['x_better_runs']} of {result['runs']} runs")


def main(argv: Sequence[str] | None = None, prog: str = "python -m experiments paired") -> int:
    parser = argparse.ArgumentParser(prog=prog,
                                     description="Paired per-seed difference X − Y of two arms or runs.")
    parser.add_argument("x", metavar="X", help="RAW_DIR:ARM or FILE.json:KEY.KEY...")
    parser.add_argument("y", metavar="Y", help="RAW_DIR:ARM or FILE.json:KEY.KEY...")
    parser.add_argument("--metric", default="reward",
                        help="episode metric of RAW_DIR:ARM (default reward; collision, cumulative_jerk, ...)")
    parser.add_argument("--offline", action="store_true",
                        help="RAW_DIR:ARM: score the evaluation after the offline phase")
    parser.add_argument("--lower-is-better", action="store_true", help="a cost (jerk, collision): report Y − X")
    args = parser.parse_args(argv)
    evaluation = "offline_evaluation" if args.offline else "evaluation"
    try:
        x, y = (load_scores(s, args.metric, evaluation) for s in (args.x, args.y))
        result = pair(x, y, higher_is_better=not args.lower_is_better)
    except ValueError as exc:
        parser.error(str(exc))
    print(format_pair(x, y, result, args.metric, higher_is_better=not args.lower_is_better))
    return 0
