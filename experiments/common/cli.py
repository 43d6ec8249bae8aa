"""What every harness command line shares: options, seeds, optional packages and :func:`harness_main`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from experiments.common.names import MAX_SEED, SCENARIO_BASES
from experiments.common.records import command_line
from experiments.common.runner import UnitsFailedError
from sb3_ua2c.cli_args import json_object_arg

#: The pip extra of ``sb3-ua2c`` that installs each optional module a harness may need.
EXTRAS = {"rliable": "peers", "ray": "peers", "structlog": "peers", "d3rlpy": "peers", "ogbench": "ogbench"}
#: d3rlpy pins an older gymnasium: it is installed on top of the ``peers`` extra without its pins.
D3RLPY_INSTALL = "pip install --no-deps d3rlpy==2.8.1 gym==0.26.2"


class MissingExtraError(ValueError):
    """A run needs a module that is not installed; the message names the ``pip install`` that adds it."""


def harness_parent(*, seeds: str, work: str, workers: int | None = 2,
                   workers_help: str = "local processes at once, each unit in a fresh process (default: 2)",
                   quick: str = "a tiny budget: a smoke test", budget: str | None = None, raw: str | None = None,
                   scenarios: bool = False, rerun: bool = False) -> argparse.ArgumentParser:
    """The parent parser of the options every harness has and of those some have (given their help texts)."""
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
    if budget is not None:
        parent.add_argument("--budget", type=budget_arg, default={}, help=budget)
    if raw is not None:
        parent.add_argument("--raw", default=None, help=f"per-unit records (default: {raw})")
    if scenarios:
        parent.add_argument("--scenarios", choices=list(SCENARIO_BASES), default="test",
                            help="evaluation scenarios: validation (choices, tuning), test (reported numbers; "
                            "default), figure2 (Figure 2's held-out scenarios, used by UA2C's earlier choices)")
    if rerun:
        parent.add_argument("--rerun", action="store_true",
                            help="delete the stored records of the selected arms and seeds first, so they run again")
    return parent


def budget_arg(text: str) -> dict[str, Any]:
    """argparse type of ``--budget``: a JSON object, or ``@FILE`` naming a file that holds one."""
    if text.startswith("@"):
        try:
            text = Path(text[1:]).read_text()
        except OSError as exc:
            raise argparse.ArgumentTypeError(f"cannot read {text[1:]!r}: {exc.strerror}") from exc
    return json_object_arg(text)


def select_seeds(seeds: Sequence[int] | None, default: Sequence[int], high: int = MAX_SEED) -> list[int]:
    """The seeds of ``--seeds`` (``default`` when ``None``) without repeats, each in ``[0, high)``."""
    chosen = list(default if seeds is None else seeds)
    if not chosen or any(isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < high for s in chosen):
        raise ValueError(f"--seeds must be integers in [0, {high}), got {chosen!r}")
    return list(dict.fromkeys(chosen))


def check_extras(modules: Iterable[str]) -> None:
    """Refuse a run whose optional ``modules`` are missing, naming the ``pip install`` that adds them."""
    missing = [m for m in dict.fromkeys(modules) if find_spec(m) is None]
    if not missing:
        return
    command = f'pip install "sb3-ua2c[{",".join(sorted({EXTRAS[m] for m in missing}))}]"'
    if "d3rlpy" in missing:
        command += f" && {D3RLPY_INSTALL}"
    raise MissingExtraError(f"this run needs {', '.join(missing)}, which is not installed: {command}")


def run_command(run: Callable[[], int]) -> int:
    """``run()``'s exit code, or its error's printed to stderr: 2 for a usage error, 1 when units failed."""
    try:
        return run()
    except (UnitsFailedError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        failed = isinstance(exc, UnitsFailedError) and not all("SeedBusyError" in tb for tb in exc.failures.values())
        return 1 if failed else 2


def harness_main(parser: argparse.ArgumentParser, argv: Sequence[str] | None, prog: str,
                 check: Callable[[argparse.Namespace], Any], run: Callable[[argparse.Namespace, Any, str], int]) -> int:
    """The skeleton of every harness command: parse ``argv``, check the Ray extra and ``check(args)`` (a ``ValueError``
    is a usage error), then ``run(args, checked, command)`` with the shell line a report records."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    try:
        if args.ray_address is not None and not args.report_only:
            check_extras(["ray"])
        checked = check(args)
    except ValueError as exc:
        parser.error(str(exc))
    return run_command(lambda: run(args, checked, command_line(prog, argv)))

