"""What every experiment report records: its command and date, paths relative to the working
directory, and JSON that strict parsers accept."""

from __future__ import annotations

import json
import math
import os
import shlex
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def strict_json(obj: Any) -> Any:
    """A copy of ``obj`` that strict JSON parsers accept: NaN -> ``None``, ±inf -> ``"inf"``/``"-inf"``."""
    if isinstance(obj, Mapping):
        return {str(k): strict_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict_json(v) for v in obj]
    if isinstance(obj, float | np.floating):
        value = float(obj)
        if math.isnan(value):
            return None
        return value if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(obj, np.integer):
        return int(obj)
    return obj

def recorded_path(path: str | os.PathLike) -> str:
    """``path`` as a record stores it: relative to the working directory when it lies inside it
    (``results/peers_work/...``), so that committed records name no directory of the machine."""
    path = Path(path).absolute()
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)

def run_header(command: str, previous: Path | None = None) -> tuple[str, str]:
    """The command and date (UTC, to the minute) a report records: now, or, when ``previous`` (the report's
    JSON from the run) exists, the ones it recorded, so that a report rebuilt with ``--report-only``
    keeps the run's."""
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if previous is not None and Path(previous).is_file():
        recorded = json.loads(Path(previous).read_text())
        command, date = recorded.get("command") or command, recorded.get("date") or date
    return command, date

def command_line(prog: str, argv: Sequence[str]) -> str:
    """The invoking command as a shell line: ``prog`` then the arguments, quoted where needed."""
    return " ".join([prog, *map(shlex.quote, argv)])


__all__ = ["command_line", "recorded_path", "run_header", "strict_json"]
