"""``python -m sb3_ua2c.diagnostics CHECKPOINT DATASET [--n-histories N --seed S --json OUT]``: the
diagnostics of :mod:`sb3_ua2c.diagnostics` for a UA2C checkpoint on histories of an offline dataset."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_ua2c.checks import check_int
from sb3_ua2c.diagnostics import dataset_batch, diagnose, format_report
from sb3_ua2c.offline import OfflineDatasetError, check_spaces_match, load_dataset
from sb3_ua2c.ua2c import UA2C


def load_inputs(checkpoint: str | Path, dataset: str | Path, device: str = "cpu") -> tuple[UA2C, Any]:
    """
    Load a UA2C checkpoint and an offline dataset (:func:`sb3_ua2c.offline.load_dataset`) and check
    that the dataset's spaces are the checkpoint's.

    :raises ValueError: naming ``CHECKPOINT`` or ``DATASET`` when a file is missing or does not fit
    """
    if not Path(checkpoint).is_file():
        raise ValueError(f"CHECKPOINT: no file at {checkpoint}")
    if not Path(dataset).exists():
        raise ValueError(f"DATASET: no dataset at {dataset}")
    try:
        data = load_dataset(dataset)
    except OfflineDatasetError as exc:
        raise ValueError(f"DATASET: {exc}") from exc
    model = UA2C.load(checkpoint, device=device)
    try:
        check_spaces_match(data.observation_space, data.action_space, model, what=f"DATASET {dataset}")
    except OfflineDatasetError as exc:
        raise ValueError(str(exc).replace("the environment", f"the CHECKPOINT {checkpoint}")) from exc
    return model, data


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sb3_ua2c.diagnostics", description="Diagnostics of a UA2C checkpoint on an offline dataset (docs/diagnostics.md).")
    parser.add_argument("checkpoint", metavar="CHECKPOINT", help="a UA2C checkpoint (.zip)")
    parser.add_argument("dataset", metavar="DATASET", help="an offline dataset directory (Minari format)")
    parser.add_argument("--n-histories", type=int, default=512, help="histories drawn from the dataset")
    parser.add_argument("--seed", type=int, default=0, help="seeds the draw and the candidates' noise")
    parser.add_argument("--json", default=None, help="also write the metrics to this JSON file")
    args = parser.parse_args(argv)
    try:
        check_int("--n-histories", args.n_histories, low=2)
        model, dataset = load_inputs(args.checkpoint, args.dataset)
        values = diagnose(model, dataset_batch(model, dataset.episodes, args.n_histories, args.seed), args.seed)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_report(values))
    if args.json:
        record = {"checkpoint": str(args.checkpoint), "dataset": str(args.dataset),
                  "n_histories": args.n_histories, "seed": args.seed, "metrics": values}
        Path(args.json).write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
