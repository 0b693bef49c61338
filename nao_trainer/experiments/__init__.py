"""Research questions answered offline: policy comparisons, the personalisation evaluation, sweeps, their reports."""
