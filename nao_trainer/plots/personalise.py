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
    """Left: mean score per session (95 % CI over users) of each pipeline by assessment length, the
    baselines that do not assess as horizontal lines. Right: the paired difference to the best fixed
    level (95 % CI over users), where the intervals are narrow enough to read."""
    plt = pyplot()
    fig, (ax, dx) = plt.subplots(1, 2, figsize=(13, 4.8))
    for name, (color, label) in _FLAT_STYLE.items():
        entry = next((s for s in summary if s["policy"] == name), None)
        if entry is not None:
            ax.axhline(entry["score"], color=color, ls="--", lw=1.2, label=f"{label} ({entry['score']:.1f})")
            if entry.get("d_reference") is not None and name != "best-fixed":
                dx.axhline(entry["d_reference"], color=color, ls="--", lw=1.2,
                           label=f"{label} ({entry['d_reference']:+.2f})")
    dx.axhline(0.0, color=_FLAT_STYLE["best-fixed"][0], lw=1.0)
    for name, (color, label) in _PIPELINE_STYLE.items():
        rows = sorted((s for s in summary if s["policy"] == name), key=lambda s: s["assessment"])
        if not rows:
            continue
        x = np.array([s["assessment"] for s in rows])
        for axis, key, ci_key in ((ax, "score", "score_ci"), (dx, "d_reference", "d_reference_ci")):
            y = np.array([s[key] for s in rows])
            lo = np.array([s[ci_key][0] if s[ci_key] else s[key] for s in rows])
            hi = np.array([s[ci_key][1] if s[ci_key] else s[key] for s in rows])
            axis.plot(x, y, "o-", color=color, label=label, ms=4)
            axis.fill_between(x, lo, hi, color=color, alpha=0.15)
    for axis in (ax, dx):
        axis.set_xlabel("assessment turns (blocks at levels 2, 3, 4; included in the 25-turn session)")
    ax.set_ylabel("score per session (equation 1)")
    dx.set_ylabel("score minus the best fixed level's (paired)")
    ax.legend(fontsize=7, loc="lower left")
    dx.legend(fontsize=7, loc="lower left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
