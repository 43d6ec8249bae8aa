"""``python -m experiments.peers`` (see ``--help``)."""

import sys

from experiments.peers.cli import main

if __name__ == "__main__":
    sys.exit(main())
