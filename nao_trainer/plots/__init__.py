"""Figures (matplotlib, imported lazily by the commands that draw)."""
from __future__ import annotations

from nao_trainer.errors import UserError

PLOTS_HINT = "pip install 'nao-trainer[plots]'"


def pyplot():
    """``matplotlib.pyplot`` with the non-interactive Agg backend; a missing matplotlib is a UserError."""
    try:
        import matplotlib
    except ImportError:
        raise UserError(f"figures need matplotlib: {PLOTS_HINT}") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
