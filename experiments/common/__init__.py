"""What the experiment harnesses share: units and executors, budgets, estimates, names, records and statistics."""
