"""Figures of policy comparisons (``nao-trainer evaluate``) and hyper-parameter sweeps (``nao-trainer sweep``)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.plots import pyplot


def _err(entry: dict[str, Any], key: str) -> tuple[float, float]:
    ci = entry.get(f"{key}_ci")
    if ci is None:
        return 0.0, 0.0
    return entry[key] - ci[0], ci[1] - entry[key]


def plot_evaluation(summary: list[dict[str, Any]], title: str, path: Path) -> Path:
    """Score and engagement per policy (means with 95 % intervals over users and seeds, or over people for session users)."""
    plt = pyplot()
    names = [s["policy"] for s in summary]
    y = np.arange(len(names))
    fig, axes = plt.subplots(1, 3, figsize=(13, 0.35 * len(names) + 1.8), sharey=True)
    for ax, key, label in zip(axes, ("score", "regret", "engagement"),
                              ("score per episode", "regret vs per-user oracle", "engagement per turn")):
        err = np.array([_err(s, key) for s in summary]).T
        colors = ["#55a868" if n.startswith("usp") else "#8172b3" if n == "oracle" else "#4c72b0" for n in names]
        ax.barh(y, [s[key] for s in summary], xerr=err, color=colors, capsize=2)
        ax.set_xlabel(label)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, names)
    axes[0].invert_yaxis()
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_sweep(points: list[dict[str, Any]], param: str, path: Path) -> Path:
    """Final expected score (mean over seeds, 95 % band) against one swept hyper-parameter, per user model."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for user in dict.fromkeys(p["user"] for p in points):
        mine = sorted((p for p in points if p["user"] == user), key=lambda p: p["value"])
        x = np.array([p["value"] for p in mine])
        m = np.array([p["score"] for p in mine])
        lo = np.array([p["score_ci"][0] if p["score_ci"] else p["score"] for p in mine])
        hi = np.array([p["score_ci"][1] if p["score_ci"] else p["score"] for p in mine])
        ax.plot(x, m, label=user)
        ax.fill_between(x, lo, hi, alpha=0.2)
    ax.set_xlabel(param)
    ax.set_ylabel("expected score per episode (frozen policy)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_sweep_grid(results: list[dict[str, Any]], names: tuple[str, str], path: Path) -> Path:
    """Final expected score over a grid of two swept hyper-parameters: one heat map per user model."""
    plt = pyplot()
    users = list(dict.fromkeys(r["user"] for r in results))
    xs = sorted({r[names[0]] for r in results})
    ys = sorted({r[names[1]] for r in results})
    fig, axes = plt.subplots(1, len(users), figsize=(3.6 * len(users) + 1, 3.6), squeeze=False)
    for ax, user in zip(axes[0], users):
        grid = np.full((len(ys), len(xs)), np.nan)
        for r in results:
            if r["user"] == user:
                grid[ys.index(r[names[1]]), xs.index(r[names[0]])] = r["score"]
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(xs)), [f"{v:.3g}" for v in xs], fontsize=7, rotation=45)
        ax.set_yticks(range(len(ys)), [f"{v:.3g}" for v in ys], fontsize=7)
        ax.set_xlabel(names[0])
        ax.set_ylabel(names[1])
        ax.set_title(str(user), fontsize=9)
        fig.colorbar(im, ax=ax, label="expected score (frozen policy)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
