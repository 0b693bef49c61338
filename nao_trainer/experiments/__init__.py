"""Offline research questions (what `nao-trainer evaluate` and the results measure)."""
