"""The study figure: participants compared (score and engagement per session, level over turns)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nao_trainer.data.study import Study
from nao_trainer.plots import pyplot

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
          "tab:olive", "tab:cyan")


def plot_study(study: Study, path: Path) -> Path:
    """Three panels: total score per session, mean engagement per session (one colour per pseudonym,
    sessions in order of date), and each session's level turn by turn."""
    plt = pyplot()
    people = list(dict.fromkeys(s.row["pseudonym"] for s in study.sessions))
    color = {p: COLORS[i % len(COLORS)] for i, p in enumerate(people)}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), constrained_layout=True)
    x = np.arange(1, len(study.sessions) + 1)
    for ax, key, label in ((axes[0], "score", "total score (eq. 1)"), (axes[1], "engagement", "mean engagement")):
        for p in people:
            idx = [i for i, s in enumerate(study.sessions) if s.row["pseudonym"] == p]
            vals = [np.nan if study.sessions[i].row[key] is None else study.sessions[i].row[key] for i in idx]
            ax.plot(x[idx], vals, "o-", color=color[p], label=p)
        ax.set(xlabel="session (by date)", ylabel=label, xticks=x)
    axes[1].set_ylim(-0.05, 1.05)
    offsets = {p: (i - (len(people) - 1) / 2) * 0.08 for i, p in enumerate(people)}  # keep the lines apart
    for s in study.sessions:
        p = s.row["pseudonym"]
        turns = np.arange(1, len(s.levels) + 1)
        levels = np.asarray(s.levels, dtype=float) + offsets[p]
        axes[2].step(turns, levels, where="mid", color=color[p], alpha=0.5, lw=1.0)
        failed = np.asarray(s.success) == 0
        axes[2].scatter(turns[~failed], levels[~failed], s=12, color=color[p], zorder=3)
        axes[2].scatter(turns[failed], levels[failed], s=22, marker="x", color=color[p], zorder=3)
    axes[2].set(xlabel="turn", ylabel="level (dot: success, x: failure)", yticks=[1, 2, 3, 4], ylim=(0.5, 4.5),
                title="level over turns")
    axes[0].legend(title="pseudonym", fontsize=8)
    axes[0].set_title("score per session")
    axes[1].set_title("engagement per session")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
