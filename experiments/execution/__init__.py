"""The execution-rule study: ``python -m experiments execution``."""
