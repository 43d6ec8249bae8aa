"""``python -m experiments.fig2`` (see ``--help``)."""

import sys

from experiments.fig2.cli import main

if __name__ == "__main__":
    sys.exit(main())
