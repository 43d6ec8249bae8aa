"""``python -m envs <command>``: the traffic job's command line (:mod:`envs.cli`, console script ``ua2c``)."""

import sys

from envs.cli import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m envs"))
