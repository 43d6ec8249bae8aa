"""Analyses across runs: ``python -m experiments paired``."""
