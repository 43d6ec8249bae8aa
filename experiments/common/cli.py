"""What every harness command line shares: the options of a run (:func:`harness_parent`), the seeds they
select (:func:`select_seeds`), the optional packages a run needs, checked before any unit runs
(:func:`check_extras`), and the command and exit code of a finished run (:func:`run_command`).

Each experiment (``fig2``, ``peers``, ``ogbench``, ``execution``) builds its parser on
:func:`harness_parent` and adds only its own options::

    parser = argparse.ArgumentParser(prog=PROG, parents=[harness_parent(seeds="0 1 2", work="<out>/x_work")])
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence
from importlib.util import find_spec

from experiments.common.names import MAX_SEED
from experiments.common.runner import UnitsFailedError

#: The pip extra of ``sb3-ua2c`` that installs each optional module a harness may need.
EXTRAS = {"rliable": "peers", "ray": "peers", "structlog": "peers", "d3rlpy": "peers", "ogbench": "ogbench"}
#: d3rlpy pins an older gymnasium: it is installed on top of the ``peers`` extra without its pins.
D3RLPY_INSTALL = "pip install --no-deps d3rlpy==2.8.1 gym==0.26.2"


class MissingExtraError(ValueError):
    """A run needs a module that is not installed; the message names the ``pip install`` that adds it."""


def harness_parent(
    *,
    seeds: str,
    work: str,
    workers: int | None = 2,
    workers_help: str = "local processes at once, each unit in a fresh process (default: 2)",
    quick: str = "a tiny budget: a smoke test",
) -> argparse.ArgumentParser:
    """The parent parser of the options every harness has: ``--seeds --out --work --workers --ray-address
    --quick --report-only``.

    :param seeds: the default seeds, as the help text says them (``--seeds`` itself defaults to ``None``:
        :func:`select_seeds` applies the default)
    :param work: the default work directory, as the help text says it (``--work`` defaults to ``None``)
    :param workers: the default of ``--workers`` (``None``: the experiment chooses after parsing)
    :param workers_help: help text of ``--workers``
    :param quick: help text of ``--quick``
    """
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--seeds", type=int, nargs="+", default=None, metavar="SEED",
                        help=f"run seeds (default: {seeds})")
    parent.add_argument("--out", default="results", help="report directory (default: results)")
    parent.add_argument("--work", default=None,
                        help=f"datasets, checkpoints and unit records (default: {work}; on a Ray cluster a "
                             "filesystem every node shares)")
    parent.add_argument("--workers", type=int, default=workers, help=workers_help)
    parent.add_argument("--ray-address", default=None, metavar="ADDRESS",
                        help="run the units on a Ray cluster ('auto', or HOST:PORT of `ray start --head`), one CPU "
                             "and a fresh process per unit")
    parent.add_argument("--quick", action="store_true", help=quick)
    parent.add_argument("--report-only", action="store_true", help="only rebuild the report from the stored records")
    return parent


def select_seeds(seeds: Sequence[int] | None, default: Sequence[int], high: int = MAX_SEED) -> list[int]:
    """The seeds of ``--seeds`` without repeats, in the order given (``default`` when not given).

    :param seeds: the parsed ``--seeds`` (``None``: not given)
    :param default: the seeds of a run without ``--seeds``
    :param high: seeds must lie in ``[0, high)`` (seed ranges of the datasets and scenarios)
    :raises ValueError: naming ``--seeds``
    """
    chosen = list(default if seeds is None else seeds)
    if not chosen or any(isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < high for s in chosen):
        raise ValueError(f"--seeds must be integers in [0, {high}), got {chosen!r}")
    return list(dict.fromkeys(chosen))


def check_extras(modules: Iterable[str]) -> None:
    """Refuse a run whose optional modules are missing, before any unit runs (a missing report
    dependency would otherwise fail only after hours of units).

    :param modules: top-level module names, keys of :data:`EXTRAS`
    :raises MissingExtraError: naming the missing modules and the ``pip install "sb3-ua2c[<extra>]"`` that adds them
    """
    missing = [m for m in dict.fromkeys(modules) if find_spec(m) is None]
    if not missing:
        return
    command = f'pip install "sb3-ua2c[{",".join(sorted({EXTRAS[m] for m in missing}))}]"'
    if "d3rlpy" in missing:
        command += f" && {D3RLPY_INSTALL}"
    raise MissingExtraError(f"this run needs {', '.join(missing)}, which is not installed: {command}")


def run_command(run: Callable[[], int]) -> int:
    """``run()``'s exit code, or the exit code of its error printed to stderr: 2 for a usage error (a bad
    argument, a missing file or record), 1 when units failed."""
    try:
        return run()
    except UnitsFailedError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


__all__ = ["D3RLPY_INSTALL", "EXTRAS", "MissingExtraError", "check_extras", "harness_parent", "run_command",
           "select_seeds"]
