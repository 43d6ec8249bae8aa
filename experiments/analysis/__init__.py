"""Analyses across runs: ``python -m experiments paired`` (the paired per-seed difference of any two arms,
within one run or across runs)."""
