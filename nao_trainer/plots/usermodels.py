"""Figures of the user models, like the paper's Figures 4 and 5 (matplotlib, imported lazily).

* ``users.png`` (Figure 4): for two example sessions, per-turn engagement over the session
  (filled markers = success) and success rate / mean engagement per level.
* ``clusters.png`` (Figure 5): MDS scatter of the user models coloured by cluster, cluster means
  of success per level and of engagement per level.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from nao_trainer.core.usermodel import mds_projection
from nao_trainer.learn.fit_source import FittedSource, engagement_signals
from nao_trainer.learn.fitting import FitResult, Turns
from nao_trainer.plots import pyplot

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray")


def example_sessions(result: FitResult, count: int = 2) -> list[str]:
    """The sessions closest to the centres of the largest-``p4`` clusters (one per cluster)."""
    um, cl = result.user_models, result.clustering
    picks = []
    for cid in np.argsort(-cl.centers[:, 3])[:count] + 1:
        members = np.flatnonzero(cl.labels == cid)
        d = np.linalg.norm(um.features[members] - cl.centers[cid - 1], axis=1)
        picks.append(um.sessions[int(members[np.argmin(d)])])
    return picks


def plot_users(result: FitResult, turns: Turns, path: Path, sessions: list[str] | None = None,
               signals: dict[str, dict[int, np.ndarray]] | None = None) -> Path:
    """Figure 4: engagement over the session and per-level success/engagement of example users.

    ``signals[session][turn]`` (optional) is the turn's per-sample normalised engagement; it is
    drawn as a continuous line behind the per-turn means (turn k spans k-0.5..k+0.5 on the x axis).
    """
    plt = pyplot()
    from matplotlib.lines import Line2D

    sessions = sessions or example_sessions(result)
    fig, axes = plt.subplots(len(sessions), 2, figsize=(11, 3.2 * len(sessions)), squeeze=False,
                             gridspec_kw={"width_ratios": [2.2, 1]})
    by_id = dict(zip(result.user_models.sessions, result.clustering.labels))
    for row, name in enumerate(sessions):
        sel = turns.session == name
        e, ok, lv = turns.engagement[sel], turns.success[sel], turns.level[sel]
        x = np.arange(1, sel.sum() + 1)
        ax = axes[row, 0]
        series = (signals or {}).get(name)
        if series:  # rows are turns 1..n in order (the importer checks the logfile's numbering)
            for k in x:
                y = series.get(int(k))
                if y is not None and len(y):
                    ax.plot(k - 0.5 + (np.arange(len(y)) + 0.5) / len(y), y, color="0.6", lw=0.7)
        else:
            ax.plot(x, e, color="0.5", lw=1)
        ax.scatter(x[ok], e[ok], c=[COLORS[l - 1] for l in lv[ok]], marker="o", zorder=3)
        ax.scatter(x[~ok], e[~ok], facecolors="none", edgecolors=[COLORS[l - 1] for l in lv[~ok]], marker="o", zorder=3)
        ax.set(xlabel="turn", ylabel="engagement (normalised)", ylim=(-0.02, 1.02),
               title=f"{name} (cluster {by_id[name]}): filled = success, open = failure")
        handles = [Line2D([], [], ls="", marker="o", color=COLORS[i], label=f"L{i + 1}") for i in range(4)]
        ax.legend(handles=handles, loc="upper right", fontsize=8, ncols=4)
        um = result.user_models.row(name)
        ax = axes[row, 1]
        pos = np.arange(4)
        ax.bar(pos - 0.2, um[:4], 0.4, label="success rate")
        ax.bar(pos + 0.2, um[4:], 0.4, label="mean engagement")
        ax.set(xticks=pos, xticklabels=[f"L{i}" for i in range(1, 5)], ylim=(0, 1.05), title="per level")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_clusters(result: FitResult, mds: np.ndarray, path: Path) -> Path:
    """Figure 5: MDS scatter by cluster, cluster mean success and engagement per level."""
    plt = pyplot()
    cl = result.clustering
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for cid in range(1, cl.k + 1):
        pts = mds[cl.labels == cid]
        color = COLORS[(cid - 1) % len(COLORS)]
        label = f"cluster {cid} (n={cl.sizes[cid - 1]})"
        axes[0].scatter(pts[:, 0], pts[:, 1], color=color, label=label)
        axes[1].plot(range(1, 5), cl.centers[cid - 1, :4], "o-", color=color, label=label)
        axes[2].plot(range(1, 5), cl.centers[cid - 1, 4:], "o-", color=color, label=label)
    axes[0].set(title="user models (MDS)", xlabel="MDS 1", ylabel="MDS 2")
    axes[1].set(title="cluster mean success", xlabel="level", ylabel="P(success)", ylim=(0, 1.05), xticks=range(1, 5))
    axes[2].set(title="cluster mean engagement", xlabel="level", ylabel="engagement", xticks=range(1, 5))
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_all(result: FitResult, turns: Turns, mds: np.ndarray, out_dir: Path,
             signal_of: "Callable[[str], dict[int, np.ndarray] | None] | None" = None) -> list[Path]:
    """Both figures into ``out_dir``; ``signal_of(session)`` may supply per-sample engagement."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    examples = example_sessions(result)
    signals = {s: sig for s in examples if signal_of and (sig := signal_of(s))}
    return [plot_users(result, turns, out / "users.png", examples, signals),
            plot_clusters(result, mds, out / "clusters.png")]


def draw_fit(fitted: "FittedSource", out_dir: Path) -> list[Path]:
    """The figures of ``nao-trainer fit``: MDS of the user models, example users with their signal."""
    result = fitted.result
    mds = mds_projection(result.user_models.features, seed=fitted.seed)
    signal_of = None if fitted.source.is_file() else engagement_signals(fitted.source, fitted.compat)
    return plot_all(result, fitted.turns, mds, out_dir, signal_of)
