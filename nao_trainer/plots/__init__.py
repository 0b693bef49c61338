"""Figures (matplotlib, imported lazily by the commands that draw)."""
