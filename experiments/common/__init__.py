"""What the experiment harnesses share: the unit runner (local processes or Ray), budgets and
their cost model, seed and method names, records, and run-level statistics."""
