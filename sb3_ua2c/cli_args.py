"""argparse argument types shared by the command lines of sb3-ua2c (``python -m envs``,
``python -m experiments fig2``, ``python -m experiments peers``)."""

from __future__ import annotations

import argparse
import json
import math
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
