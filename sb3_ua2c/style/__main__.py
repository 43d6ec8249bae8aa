"""``python -m sb3_ua2c.style``: the same command line as ``python -m sb3_ua2c style``."""

from sb3_ua2c.style.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
