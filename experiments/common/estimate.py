"""Run-time estimates printed before a run: the committed records' CPU seconds per step of each kind of unit."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common.runner import list_schedule_seconds

RESULTS = Path(__file__).resolve().parents[2] / "results"


def recorded(pattern: str, results: Path = RESULTS) -> list[dict[str, Any]]:
    """The JSON files under ``results`` matching ``pattern`` (e.g. ``"**/ogbench.json"``), parsed, in path order."""
    return [json.loads(path.read_text()) for path in sorted(results.glob(pattern))]


def seconds_per_size(samples: Iterable[tuple[str, float, float]]) -> dict[str, float]:
    """Seconds per unit of size of each kind, from ``(kind, seconds, size)`` samples (a size <= 0 is skipped)."""
    seconds: dict[str, float] = {}
    sizes: dict[str, float] = {}
    for kind, s, size in samples:
        if size > 0:
            seconds[kind] = seconds.get(kind, 0.0) + float(s)
            sizes[kind] = sizes.get(kind, 0.0) + float(size)
    return {kind: seconds[kind] / sizes[kind] for kind in seconds}


def estimate(rates: Mapping[str, float], sizes: Mapping[str, float]) -> dict[str, float]:
    """Seconds of each kind at ``sizes`` (a kind without a rate: the median rate of the others; 0 without any)."""
    fallback = float(np.median(list(rates.values()))) if rates else 0.0
    return {kind: rates.get(kind, fallback) * size for kind, size in sizes.items()}


def wall_seconds(units: Sequence[float], workers: int) -> float:
    """Wall seconds of ``units`` (CPU seconds each) run longest first on ``workers`` cores."""
    return list_schedule_seconds(sorted(units, reverse=True), workers) if units else 0.0

