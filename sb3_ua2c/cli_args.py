"""argparse argument types shared by the command lines of sb3-ua2c (``python -m sb3_ua2c``, ``fig2``, ``style``)."""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any


def json_object_arg(text: str) -> dict[str, Any]:
    """argparse type: a JSON object (``dict``), else a clear usage error."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON: {exc}") from exc
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def float_arg(text: str) -> float:
    """argparse type: a float other than NaN (``"inf"`` is accepted)."""
    value = float(text)
    if math.isnan(value):
        raise argparse.ArgumentTypeError("NaN is not a valid value")
    return value


def threshold_arg(text: str) -> float | str:
    """argparse type of δ (Eq. 7): ``"auto"`` or a float other than NaN (``"inf"`` = fixed chunks)."""
    return "auto" if text == "auto" else float_arg(text)


def run_header(command: str, previous: Path | None = None) -> tuple[str, str]:
    """The command and date (UTC, to the minute) a report records: now, or, when ``previous`` (the report's
    JSON from the run) exists, the ones it recorded, so that a report rebuilt with ``--report-only``
    keeps the run's."""
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if previous is not None and Path(previous).is_file():
        recorded = json.loads(Path(previous).read_text())
        command, date = recorded.get("command") or command, recorded.get("date") or date
    return command, date

