"""Figure of one live session: level, outcome and feedback per turn, running score, engagement."""
from __future__ import annotations

from pathlib import Path

from nao_trainer.plots import pyplot
from nao_trainer.session.record import read_turns


#: The robot's feedback in the turn table's codes, in the words of the dialogue and the turn line.
FEEDBACK = {"1": ("encouraging", "^", "tab:olive"), "2": ("challenging", "v", "tab:brown")}


def plot_session(path: Path) -> Path:
    """``session.png`` in the session folder: level per turn (success/failure, feedback), running
    score and engagement, for a look at a session without reading the table."""
    plt = pyplot()
    fig = session_figure(path)
    out = Path(path) / "session.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def session_figure(path: Path):
    """The figure of :func:`plot_session` (not saved): the robot's feedback is a marker above the turn's level,
    named in the legend as the turn line names it ("robot feedback: encouraging")."""
    plt = pyplot()

    rows = [r for r in read_turns(path) if r["success"] in ("True", "False")]
    if not rows:
        raise ValueError(f"{path}: no completed turn to plot")
    turns = [int(r["turn"]) for r in rows]
    levels = [int(r["level"]) for r in rows]
    ok = [r["success"] == "True" for r in rows]
    running = list(_accumulate(int(r["score"]) for r in rows))
    eng = [float(r["engagement"]) if r["engagement"] else float("nan") for r in rows]
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True, constrained_layout=True)
    ax = axes[0]
    ax.step(turns, levels, where="mid", color="0.6", lw=1)
    ax.scatter([t for t, s in zip(turns, ok) if s], [lv for lv, s in zip(levels, ok) if s], c="tab:green", label="success", zorder=3)
    ax.scatter([t for t, s in zip(turns, ok) if not s], [lv for lv, s in zip(levels, ok) if not s], c="tab:red", marker="x", label="failure", zorder=3)
    for code, (word, marker, colour) in FEEDBACK.items():
        at = [(t, int(r["level"]) + 0.3) for r, t in zip(rows, turns) if r["feedback"] == code]
        if at:
            ax.scatter(*zip(*at), marker=marker, c=colour, s=22, label=f"robot feedback: {word}", zorder=3)
    ax.set(ylabel="level", yticks=[1, 2, 3, 4], ylim=(0.5, 4.7), title=f"session {Path(path).name}")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    axes[1].plot(turns, running, marker=".", color="tab:blue")
    axes[1].set(ylabel="total score (eq. 1)")
    axes[2].plot(turns, eng, marker="o", color="tab:purple")
    axes[2].set(ylabel="engagement", xlabel="turn", ylim=(-0.05, 1.05))
    if all(e != e for e in eng):  # all NaN
        axes[2].text(0.5, 0.5, "no engagement (EEG off or no clean signal)", ha="center", va="center",
                     transform=axes[2].transAxes, color="0.4")
    return fig


def _accumulate(values):
    total = 0
    for v in values:
        total += v
        yield total
