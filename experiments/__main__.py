"""``python -m experiments <command> [options]``: the one entry point of the research harnesses (:data:`COMMANDS`)."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

PROG = "python -m experiments"

#: command -> (module with ``main(argv, prog)``, what it does)
COMMANDS = {
    "fig2": ("experiments.fig2.cli", "the paper's Figure 2 on MixedTraffic-v0 over several seeds"),
    "peers": ("experiments.peers.cli", "the head-to-head with SB3, sb3-contrib and d3rlpy"),
    "peers-tuning": ("experiments.peers.tuning", "the head-to-head's tuning on validation scenarios"),
    "ogbench": ("experiments.ogbench.cli", "an OGBench single task, offline then online"),
    "acting": ("experiments.acting.cli", "acting rules (selection x execution) on frozen checkpoints"),
    "execution": ("experiments.execution.cli", "execution rules against fixed chunks and matched controls"),
    "compare-runs": ("experiments.fig2.compare_runs", "two Figure-2 reports paired run by run"),
    "pool-replicates": ("experiments.fig2.pool_replicates", "Figure 2 (c) pooled over online replicates"),
    "paired": ("experiments.analysis.paired", "the paired difference of two arms across runs"),
    "make-checkpoint": ("experiments.pretrained.make_checkpoint", "the pre-trained checkpoint of rl-trained-agents"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    return "\n".join([f"usage: {PROG} <command> [options]   ({PROG} <command> --help)", "", "commands:",
                      *(f"  {name:{width}}  {text}" for name, (_, text) in COMMANDS.items())])


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``argv[0]``'s command with the rest of ``argv``; its exit code (2 for an unknown command)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    if argv[0] not in COMMANDS:
        print(f"{usage()}\n\nerror: unknown command {argv[0]!r}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[argv[0]][0])
    return module.main(argv[1:], prog=f"{PROG} {argv[0]}") or 0


if __name__ == "__main__":
    sys.exit(main())
