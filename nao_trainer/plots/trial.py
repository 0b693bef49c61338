"""Figures of a controlled study: an outcome per arm and session (``study analyse``), power curves (``study power``)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.plots import pyplot

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
LABELS = {"score": "total score per session (eq. 1)", "engagement": "mean engagement", "success_rate": "success rate"}


def plot_outcomes(report: Any, outcome: str, path: Path) -> Path:
    """Left: each participant's outcome over sessions, one colour per arm. Right: the pre-registered
    model's arm effects against the reference arm with 95 % intervals."""
    plt = pyplot()
    arms = list(dict.fromkeys(d["arm"] for d in report.data))
    color = {a: COLORS[i % len(COLORS)] for i, a in enumerate(sorted(arms))}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for person in dict.fromkeys(d["participant"] for d in report.data):
        rows = sorted((d for d in report.data if d["participant"] == person), key=lambda d: d["session"])
        axes[0].plot([d["session"] for d in rows], [d[outcome] for d in rows], "o-", alpha=0.6,
                     color=color[rows[0]["arm"]])
    for a in sorted(arms):
        axes[0].plot([], [], "o-", color=color[a], label=a)
    sessions = sorted({d["session"] for d in report.data})
    axes[0].set(xlabel="session", ylabel=LABELS.get(outcome, outcome), xticks=sessions,
                title=f"{outcome}: participants by arm")
    axes[0].legend(title="arm", fontsize=8)
    est = [r for r in report.rows if r["outcome"] == outcome and r["model"] == "pre-registered"
           and r["term"] != "Intercept"]
    y = np.arange(len(est))
    axes[1].errorbar([r["estimate"] for r in est], y,
                     xerr=[[r["estimate"] - r["ci_low"] for r in est], [r["ci_high"] - r["estimate"] for r in est]],
                     fmt="o", color="k", capsize=4)
    axes[1].axvline(0, color="grey", lw=0.8, ls="--")
    axes[1].set(yticks=y, yticklabels=[r["term"] for r in est], xlabel="estimate (95 % CI)",
                title=f"{report.model}\nprotocol {report.protocol_sha256[:12]}")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def plot_power(report: Any, path: Path) -> Path:
    """Power of the pre-registered test per number of participants, one line per outcome and comparison."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    styles = {"score": "-", "engagement": "--", "success_rate": ":"}
    comparisons = sorted({key.split(": ", 1)[1] for key in report.power})
    for key, values in sorted(report.power.items()):
        outcome, comparison = key.split(": ", 1)
        color = COLORS[comparisons.index(comparison) % len(COLORS)]
        lo, hi = zip(*(report.interval(v) for v in values))
        ax.plot(report.ns, values, marker="o", ls=styles.get(outcome, "-"), color=color, label=key)
        ax.fill_between(report.ns, lo, hi, color=color, alpha=0.08)
    ax.axhline(0.8, color="grey", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.minorticks_off()
    ax.set(xticks=report.ns, xticklabels=[str(n) for n in report.ns], ylim=(-0.02, 1.02),
           xlabel="participants (total, all arms)", ylabel=f"power (alpha {report.alpha:g})",
           title=f"{report.name}: {report.reps} simulated studies per N ({report.users} users)")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
