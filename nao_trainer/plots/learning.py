"""Figures of policy training: learning curves (paper Figure 7) and policies at S0 (Figure 8).

matplotlib is imported inside the functions (Agg backend): the CLI pays for it only when drawing.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.learn.training import FIGURE7, FIGURE8
from nao_trainer.plots import pyplot

if TYPE_CHECKING:  # pragma: no cover
    from nao_trainer.core.qlearning import QConfig
    from nao_trainer.learn.training import GridResult

METHOD_COLORS = {"performance": "#4c72b0", "shaping": "#dd8452", "qaug": "#55a868"}


def method_label(method: str, config: "QConfig") -> str:
    """Legend text of a method with the run's weights, e.g. ``reward shaping (r + 7.5e)``."""
    return {"performance": "performance (r)", "shaping": f"reward shaping (r + {config.beta1:g}e)",
            "qaug": f"Q-augmentation (Q + {config.beta2:g}H)"}.get(method, method)


def bin_curve(values: np.ndarray, n_bins: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` (..., episodes) over consecutive bins; returns (bin centre episode, means)."""
    episodes = values.shape[-1]
    n_bins = max(1, min(n_bins, episodes))
    edges = np.linspace(0, episodes, n_bins + 1).round().astype(int)
    sums = np.add.reduceat(values, edges[:-1], axis=-1)
    means = sums / np.diff(edges)
    return (edges[:-1] + edges[1:]) / 2.0, means


def plot_learning_curves(result: "GridResult", path: Path, n_bins: int = 100) -> Path:
    """Score and engagement per episode for each cluster (rows) and method (lines), mean and 95 % band.

    Curves are binned over consecutive episodes so the trend is readable; the band is the binned
    per-episode 95 % interval of the mean over seeds.
    """
    plt = pyplot()
    curves = result.curves()
    n_rows = len(result.clusters)
    fig, axes = plt.subplots(n_rows, 2, figsize=(10, 2.8 * n_rows), squeeze=False, sharex=True)
    for c, cluster in enumerate(result.clusters):
        for col, (name, label) in enumerate((("score", "task score per episode"),
                                             ("engagement", "mean engagement per episode"))):
            ax = axes[c, col]
            for m, method in enumerate(result.spec.methods):
                x, mean = bin_curve(curves[f"{name}_mean"][c, m], n_bins)
                _, lo = bin_curve(curves[f"{name}_lo"][c, m], n_bins)
                _, hi = bin_curve(curves[f"{name}_hi"][c, m], n_bins)
                color = METHOD_COLORS.get(method)
                ax.plot(x, mean, color=color, label=method_label(method, result.spec.config), lw=1.4)
                ax.fill_between(x, lo, hi, color=color, alpha=0.25, lw=0)
            ax.set_ylabel(label)
            ax.set_title(f"user model {cluster}", fontsize=10)
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("episode")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle(f"Q-learning on simulated users: mean and 95 % band over {result.spec.seeds} seeds", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_s0_policies(result: "GridResult", path: Path) -> Path:
    """P(action | S0) per cluster (rows) and method (columns), averaged over seeds.

    Each panel notes how often the agents visited S0 on average: a rarely visited state keeps a
    near-uniform policy, which is not the same as indifference.
    """
    plt = pyplot()
    probs = result.s0_probabilities()
    visits = result.visits[..., result.s0_index].mean(axis=2)  # few visits -> still near-uniform
    n_rows, n_cols = len(result.clusters), len(result.spec.methods)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(3.2 * n_cols, 2.4 * n_rows), squeeze=False,
                             sharey=True)
    x = np.arange(mdp.N_ACTIONS)
    for c, cluster in enumerate(result.clusters):
        for m, method in enumerate(result.spec.methods):
            ax = axes[c, m]
            ax.bar(x, probs[c, m], color=METHOD_COLORS.get(method, "grey"))
            ax.set_xticks(x, mdp.ACTION_NAMES, fontsize=8)
            ax.set_ylim(0, 1)
            ax.text(0.97, 0.93, f"visits {visits[c, m]:.0f}", transform=ax.transAxes, ha="right", va="top",
                    fontsize=7, color="0.35")
            if c == 0:
                ax.set_title(method, fontsize=10)
            if m == 0:
                ax.set_ylabel(f"user model {cluster}\nP(a | S0)", fontsize=9)
    fig.suptitle(f"Learned policies at S0 = {mdp.S0} (mean over {result.spec.seeds} seeds)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def write_figures(result: "GridResult", out_dir: Path) -> dict[str, Path]:
    """Figures 7 and 8 of a training run, next to the files of ``training.write_outputs``."""
    out = Path(out_dir)
    return {"figure7": plot_learning_curves(result, out / FIGURE7), "figure8": plot_s0_policies(result, out / FIGURE8)}
