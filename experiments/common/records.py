"""What every experiment report records: its command and date, paths relative to the working
directory, JSON that strict parsers accept, and the budget a run directory was made with
(:func:`check_budget_record`)."""

from __future__ import annotations

import json
import math
import os
import shlex
import time
from collections.abc import Callable, Mapping, Sequence
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


def write_report(out: Path, name: str, summary: Mapping[str, Any], markdown: str,
                 plots: Callable[[Path], Sequence[Path]] | None = None) -> list[Path]:
    """The files of a harness's report: ``<name>.json`` (``summary`` as strict JSON), ``<name>.md`` (``markdown``)
    and the figures ``plots(out)`` draws, in ``out``; returns their paths."""
    from sb3_ua2c.pipeline import write_json

    out.mkdir(parents=True, exist_ok=True)
    files = [write_json(out / f"{name}.json", strict_json(summary)), out / f"{name}.md"]
    files[1].write_text(markdown)
    return [*files, *(plots(out) if plots is not None else [])]


def check_budget_record(path: str | os.PathLike, budget: Mapping[str, Any], what: str,
                        fields: Sequence[str] | None = None, read: Callable[[Any], Mapping[str, Any]] | None = None,
                        write: bool = True) -> None:
    """Refuse to resume a run under another budget: its stored units would be silently reused.

    ``path`` holds the budget a run was made with (JSON). When it exists, the stored budget must agree with
    ``budget`` on ``fields``; then, with ``write``, ``budget`` is recorded there (the first call of a run
    writes the record).

    :param path: the budget record (a manifest, or a stored unit's record with ``read``)
    :param budget: the budget of this call, as a plain dict (``Budget.to_dict()``)
    :param what: what the error names, e.g. ``"the run in results/peers_work"``
    :param fields: the keys that must agree (``None``: every key); others may change between calls
    :param read: the stored JSON -> the budget dict (e.g. through the budget class, so that a key added
        since the record holds its default)
    :param write: record ``budget`` at ``path`` once it agrees
    :raises ValueError: naming the keys that differ, with both values
    """
    from sb3_ua2c.pipeline import write_json

    path, now = Path(path), strict_json(budget)
    if path.is_file():
        stored = json.loads(path.read_text())
        stored = strict_json(read(stored) if read is not None else stored)
        keys = fields if fields is not None else sorted(set(stored) | set(now))
        differ = [k for k in keys if stored.get(k) != now.get(k)]
        if differ:
            details = "; ".join(f"{k}: recorded {stored.get(k)!r}, now {now.get(k)!r}" for k in differ)
            raise ValueError(f"{what} was made with another budget (differs in {differ}: {details}); pass the same "
                             "budget to resume it, or another --out/--work to start a new run")
    if write:
        write_json(path, now)


__all__ = ["check_budget_record", "command_line", "recorded_path", "run_header", "strict_json", "write_report"]
