"""``python -m experiments.ogbench`` (see ``--help``)."""

import sys

from experiments.ogbench.cli import main

if __name__ == "__main__":
    sys.exit(main())
