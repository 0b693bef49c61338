"""Offline learning: user-model fitting, simulator files, the Q-learning grid, policy files, user sets, the gym env."""
