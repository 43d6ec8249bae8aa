"""``python -m envs.style``: the same command line as ``python -m envs style``."""

from envs.style.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
