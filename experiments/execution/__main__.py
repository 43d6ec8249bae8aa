"""``python -m experiments.execution`` (see ``--help``)."""

import sys

from experiments.execution.cli import main

if __name__ == "__main__":
    sys.exit(main())
