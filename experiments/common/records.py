"""What every experiment report shares: its header, files, tables and figures, and a run's directories and budget."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shlex
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sb3_ua2c.pipeline import write_json


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
    """``path`` relative to the working directory when inside it: committed records name no machine's directory."""
    path = Path(path).absolute()
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def run_header(command: str, report: Path, report_only: bool) -> tuple[str, str, dict[str, Any]]:
    """The command and date a report records (now's, or with ``report_only`` those of the report at ``report`` that
    the rebuild replaces) and that previous report's parsed JSON (``{}`` if none)."""
    previous = json.loads(report.read_text()) if report_only and report.is_file() else {}
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    return previous.get("command") or command, previous.get("date") or date, previous


def command_line(prog: str, argv: Sequence[str]) -> str:
    """The invoking command as a shell line: ``prog`` then the arguments, quoted where needed."""
    return " ".join([prog, *map(shlex.quote, argv)])


def write_report(out: Path, name: str, summary: Mapping[str, Any], markdown: str,
                 plots: Callable[[Path], Sequence[Path]] | None = None) -> list[Path]:
    """Write ``<name>.json`` (strict JSON), ``<name>.md`` and the figures ``plots(out)`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    files = [write_json(out / f"{name}.json", strict_json(summary)), out / f"{name}.md"]
    files[1].write_text(markdown)
    return [*files, *(plots(out) if plots is not None else [])]


def check_budget_record(path: str | os.PathLike, budget: Mapping[str, Any], what: str,
                        fields: Sequence[str] | None = None, read: Callable[[Any], Mapping[str, Any]] | None = None,
                        write: bool = True) -> None:
    """Refuse a run whose budget stored at ``path`` differs from ``budget`` on ``fields``; then record ``budget``."""
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


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A Markdown table: the ``header`` cells, then one line per row of cells."""
    return [_table_row(header), "|" + "---|" * len(header), *map(_table_row, rows)]


def _table_row(cells: Sequence[Any]) -> str:
    return "| " + " | ".join(map(str, cells)) + " |"


def section(title: str, *lines: str) -> list[str]:
    """A Markdown section: a blank line, the ``## title`` heading, a blank line and ``lines``."""
    return ["", f"## {title}", "", *lines]


@contextmanager
def figure(path: Path, size: tuple[float, float]) -> Iterator[Any]:
    """A matplotlib figure (no pyplot: the caller's backend stays untouched), saved to ``path`` on leaving."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=120)
    FigureCanvasAgg(fig)
    yield fig
    fig.tight_layout()
    fig.savefig(path)


def episode_rows(episodes: Sequence[Any]) -> list[dict[str, Any]]:
    """Evaluation episodes (:class:`~envs.evaluation.EpisodeMetrics`) as JSON rows, with their jerk per step and
    without their wall time (a record of seeded episodes is the same at every run)."""
    return [{**{k: v for k, v in dataclasses.asdict(e).items() if k != "acting_seconds"}, "jerk_per_step": e.jerk_per_step}
            for e in episodes]


@dataclass(frozen=True)
class RunPaths:
    """Where a run keeps its report (``out``), records (``raw``), datasets and checkpoints (``work``) and budget."""

    NAME: ClassVar[str] = "run"
    BUDGET: ClassVar[type] = dict
    FIELDS: ClassVar[Sequence[str] | None] = None
    out: Path
    raw: Path
    work: Path

    @classmethod
    def under(cls, out: str | os.PathLike, raw: str | os.PathLike | None = None,
              work: str | os.PathLike | None = None) -> RunPaths:
        """``<out>/<NAME>_raw`` and ``<out>/<NAME>_work`` unless given; absolute, as units on a Ray cluster use them."""
        out = Path(out).resolve()
        return cls(out, Path(raw).resolve() if raw else out / f"{cls.NAME}_raw",
                   Path(work).resolve() if work else out / f"{cls.NAME}_work")

    def seed_work(self, seed: int) -> Path:
        return self.work / f"seed{seed}"

    def seed_raw(self, seed: int) -> Path:
        return self.raw / f"seed{seed}"

    @property
    def manifest(self) -> Path:
        return self.work / f"{self.NAME}_budget.json"

    def check_budget(self, budget: Any) -> None:
        """Refuse to resume the run under another budget (:func:`check_budget_record`), then record ``budget``."""
        check_budget_record(self.manifest, budget.to_dict(), f"the run in {self.work}", fields=self.FIELDS,
                            read=lambda stored: self.BUDGET.from_dict(stored).to_dict())

    def rebuilt_budget(self, report: Mapping[str, Any], default: Any) -> Any:
        """The budget a ``--report-only`` rebuild reads: the run's manifest, else its ``report``'s, else ``default``."""
        return self.recorded_budget() or (self.BUDGET.from_dict(report["budget"]) if "budget" in report else default)

    def recorded_budget(self) -> Any:
        """The budget of the last call on this run (``None`` if none); a ``ValueError`` names a bad record."""
        if not self.manifest.is_file():
            return None
        try:
            return self.BUDGET.from_dict(json.loads(self.manifest.read_text()))
        except (json.JSONDecodeError, TypeError, ValueError) as exc:
            raise ValueError(f"{self.manifest} is not a {self.BUDGET.__name__} record: {exc}") from exc
