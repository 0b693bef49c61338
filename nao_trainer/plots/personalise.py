"""The personalisation figure (``nao-trainer evaluate --personalise``): score against assessment length."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.plots import pyplot

_PIPELINE_STYLE = {"personalised": ("#c44e52", "whole pipeline (posterior EV + per-level Beta)"),
                   "posterior-ev": ("#dd8452", "posterior EV, models as fitted"),
                   "paper": ("#4c72b0", "paper: most likely cluster -> its policy")}
_FLAT_STYLE = {"oracle": ("#8172b3", "per-user oracle"), "best-fixed": ("#55a868", "best fixed level"),
               "fixed:2": ("#937860", "always level 2"), "generic": ("#7f7f7f", "generic policy (pooled data)")}


def plot_personalise(summary: list[dict[str, Any]], title: str, path: Path) -> Path:
    """Mean score per session (95 % CI over users) of each pipeline by assessment length, with the
    baselines that do not assess as horizontal lines."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for name, (color, label) in _FLAT_STYLE.items():
        entry = next((s for s in summary if s["policy"] == name), None)
        if entry is not None:
            ax.axhline(entry["score"], color=color, ls="--", lw=1.2, label=f"{label} ({entry['score']:.1f})")
    for name, (color, label) in _PIPELINE_STYLE.items():
        rows = sorted((s for s in summary if s["policy"] == name), key=lambda s: s["assessment"])
        if not rows:
            continue
        x = np.array([s["assessment"] for s in rows])
        y = np.array([s["score"] for s in rows])
        lo = np.array([s["score_ci"][0] if s["score_ci"] else s["score"] for s in rows])
        hi = np.array([s["score_ci"][1] if s["score_ci"] else s["score"] for s in rows])
        ax.plot(x, y, "o-", color=color, label=label, ms=4)
        ax.fill_between(x, lo, hi, color=color, alpha=0.15)
    ax.set_xlabel("assessment turns (blocks at levels 2, 3, 4; included in the 25-turn session)")
    ax.set_ylabel("score per session (equation 1)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
