"""Figure of one published session's offline engagement (``nao-trainer engagement --plot``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nao_trainer.data.engagement import SessionEngagement
from nao_trainer.plots import pyplot


def plot_session(result: SessionEngagement, path: Path) -> Path:
    """Save a figure: per-turn engagement (bars) and the per-sample series of every turn (line)."""
    plt = pyplot()

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 6), constrained_layout=True)
    turns = [t.turn for t in result.turns]
    eng = [np.nan if t.engagement is None else t.engagement for t in result.turns]
    ax1.bar(turns, eng, color=["tab:blue" if np.isfinite(e) else "lightgrey" for e in eng])
    for t in result.turns:
        if t.engagement is None:
            ax1.text(t.turn, 0.02, "x", ha="center", color="tab:red")
    ax1.set(xlabel="turn", ylabel="engagement (normalised)", ylim=(0, 1),
            title=f"{result.session}: listening-phase engagement "
            f"({result.compat or 'project definition'}, {result.source})")
    offset = 0.0
    for turn, s in sorted(result.series.items()):
        if len(s.t):
            ax2.plot(offset + s.t, s.normalised, lw=0.8, color="tab:blue")
            ax2.axvline(offset, color="lightgrey", lw=0.5)
            offset += float(s.t[-1]) + 1.0
    ax2.set(xlabel="listening time, turns concatenated (s)", ylabel="normalised E", ylim=(-0.02, 1.02))
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
