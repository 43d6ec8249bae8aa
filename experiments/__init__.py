"""Research harnesses of sb3-ua2c, outside the wheel: run them from a checkout as ``python -m experiments``."""
