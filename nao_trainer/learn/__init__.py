"""Offline learning: user-model fitting, simulator files, the Q-learning grid, user-specific policies, the gym env."""
