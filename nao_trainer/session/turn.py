"""A turn in flight and what a session returns: ``Turn`` builds its own row of turns.csv."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp, task
from nao_trainer.core.psychometric import SPAN_RATE, Span, level_counts, session_span
from nao_trainer.errors import DataError
from nao_trainer.learn.psychometric_prior import load_prior
from nao_trainer.ports import Answer, PhaseEngagement
from nao_trainer.tasks.base import Task


@dataclass
class Turn:
    """A turn in flight (or just played)."""

    number: int
    previous_state: int  # the MDP state the action was chosen in (START for the first turn)
    action: int
    state: int  # this turn's state (L, RF, PR)
    sequence: tuple[str, ...] = ()  # the trial's stimuli (the sequence task: its letters)
    trial: Any = None  # the task's ``tasks.base.Trial``
    fields: dict[str, Any] = field(default_factory=dict)  # the task's own row fields, set by its judgement
    start_time: str = ""
    answer: Answer | None = None
    listening: PhaseEngagement | None = None
    answering: PhaseEngagement | None = None
    success: bool | None = None
    notes: list[str] = field(default_factory=list)
    recorded: bool = False
    invalid: bool = False  # the operator marked it invalid: recorded, not learned from
    replay: bool = False  # the second go of a turn interrupted by a robot loss (same number, state, action)
    phase: str = ""  # what the policy said the turn is for (e.g. "assessment"), empty when nothing

    @classmethod
    def chosen(cls, number: int, mdp_state: int, action: int, last_success: bool | None, by: str,
               notes: list[str], phase: str) -> "Turn":
        """The turn ``by`` (a policy) chose in ``mdp_state``; ValueError for an action the state does not allow."""
        if not (0 <= action < mdp.N_ACTIONS and mdp.ACTION_MASK[mdp_state, action]):
            raise ValueError(f"policy {by} chose action {action!r}, not allowed in state {mdp.state_label(mdp_state)}")
        if mdp_state == mdp.START:
            state = int(mdp.NEXT_STATE[mdp.START, action, 0])
        else:
            state = mdp.next_state(mdp_state, action, bool(last_success))
        return cls(number, mdp_state, action, state, notes=notes, phase=phase)

    def again(self) -> "Turn":
        """The second go of an interrupted turn: same number, states, action and phase; a new sequence."""
        return Turn(self.number, self.previous_state, self.action, self.state, notes=["replay of interrupted turn"],
                    replay=True, phase=self.phase)

    @property
    def turn_state(self) -> mdp.State:
        return mdp.decode(self.state)

    def judge(self, task: Task) -> None:
        """Judge the answer with the task (equation (1) needs only success) and note why it failed."""
        assert self.answer is not None and self.trial is not None
        judgement = task.judge(self.trial, self.answer)
        self.notes += list(judgement.notes)
        self.fields = dict(judgement.fields)
        self.success = judgement.success

    def row(self, score: int | None, signed: int | None, speed: float, eeg_on: bool,
            columns: tuple[str, ...] | None = None) -> dict[str, Any]:
        """This turn's line of turns.csv, in the task's ``columns`` (the sequence task's by default). Times
        measured on the wall clock are reported in session seconds (x ``speed``); ``eeg_quality`` stays empty
        when EEG is off."""
        st = self.turn_state
        a, lis, ans = self.answer, self.listening, self.answering
        row = {
            "turn": self.number, "start_time": self.start_time, "state": self.state, "length": st.length,
            "level": st.level, "feedback": st.feedback, "previous_score": st.previous,
            "action": mdp.ACTION_NAMES[self.action], "sequence": "".join(self.sequence),
            "response": "".join(a.response) if a else "", "success": self.success, "score": score,
            "signed_score": signed,
            "reaction_time": round(a.reaction_time * speed, 3) if a and a.reaction_time is not None else None,
            "completion_time": round(a.completion_time * speed, 3) if a and a.completion_time is not None else None,
            "engagement": _round(lis.engagement if lis else None),
            "engagement_index": _round(lis.index if lis else None),
            "eeg_quality": _round(lis.quality if lis else None) if eeg_on else None,
            "answer_engagement": _round(ans.engagement if ans else None),
            "engagement_note": (lis.reason if lis.engagement is None else "") if lis
            else ("" if self.success is None else "no listening phase"),
            "notes": "; ".join(self.notes),
            "invalid": True if self.invalid else None,
            "replay": True if self.replay else None,
            "phase": self.phase,
            **self.fields,
        }
        return row if columns is None else {k: row[k] for k in columns if k in row}


@dataclass
class SessionResult:
    """What a finished (or ended) session returns to the caller."""

    path: Path | None
    status: str  # completed | robot lost | interrupted | error
    exit_code: int
    rows: list[dict[str, Any]]
    seed: int
    error: str = ""

    summary_extra: str = ""  # e.g. the resumption this result continues
    policy_summary: str = ""  # what the policy concluded (e.g. the user model the participant matched)
    span_prior: Path | None = None  # the psychometric prior of the span (default: the shipped one)
    span_rate: float = SPAN_RATE  # the success rate the span is given at (``span_rate``)
    task: Any = None  # the task played (``tasks.base.Task``); None: the sequence task

    @property
    def completed_rows(self) -> list[dict[str, Any]]:
        """The turns that count: answered, and not marked invalid by the operator (as in ``nao-trainer study``)."""
        return [r for r in self.rows if r["success"] in (True, False) and not r.get("invalid")]

    @property
    def invalid_rows(self) -> list[dict[str, Any]]:
        """Answered turns the operator marked invalid: recorded, neither learned from nor counted."""
        return [r for r in self.rows if r["success"] in (True, False) and r.get("invalid")]

    @property
    def total_score(self) -> int:
        return int(sum(r["score"] for r in self.completed_rows))

    def level_table(self) -> list[tuple[int, int, float | None]]:
        """(level, turns played, success rate) per level."""
        out = []
        for level in task.LEVELS:
            rows = [r for r in self.completed_rows if r["level"] == level]
            rate = sum(bool(r["success"]) for r in rows) / len(rows) if rows else None
            out.append((level, len(rows), rate))
        return out

    @property
    def mean_engagement(self) -> float | None:
        values = [r["engagement"] for r in self.completed_rows if r["engagement"] is not None]
        return float(np.mean(values)) if values else None

    @property
    def eeg_on(self) -> bool:
        """EEG was recorded (a turn says why it has no value otherwise than "EEG off")."""
        return any(r.get("engagement_note") != "EEG off" for r in self.completed_rows)

    @property
    def eeg_turns(self) -> int:
        """Counted turns with an engagement value (EEG present in the listening phase)."""
        return sum(r["engagement"] is not None for r in self.completed_rows)

    def _no_engagement(self) -> str:
        """Why there is no mean engagement: EEG off, or the reason the turns give (EEG on, no value)."""
        notes = [r.get("engagement_note") or "no value" for r in self.completed_rows]
        if not notes:
            return "n/a (no completed turn)"
        if set(notes) == {"EEG off"}:
            return "n/a (EEG off)"
        return f"n/a (EEG on, no value in any turn: {_most_common(notes).split('; ')[0]})"

    def span(self) -> Span | None:
        """The span at ``span_rate`` from the counted turns (None without any); DataError when the
        prior cannot be read."""
        rows = self.completed_rows
        if not rows:
            return None
        counts = level_counts([r["level"] for r in rows], [bool(r["success"]) for r in rows])
        return session_span(load_prior(self.span_prior), counts, self.span_rate)

    def span_record(self) -> dict[str, Any] | None:
        """The span for session.json and the console: rate, median, interval (letters); None without turns
        or for a task whose levels are not sequence lengths (its own line: ``Task.span``)."""
        if self._own_span():
            return None
        try:
            span = self.span()
        except (DataError, ValueError) as exc:  # an unreadable prior, or one whose lapse rules the rate out
            return {"rate": self.span_rate, "error": str(exc)}
        return None if span is None else span_dict(span)

    def _own_span(self) -> bool:
        """The task has a capacity line of its own (the span in letters, under the prior fitted on the published
        data, is the sequence task's: ``Task.published_data``)."""
        return self.task is not None and not getattr(self.task, "published_data", False)

    def span_line(self) -> str:
        """``span at 75 %: 6.1 letters [4.9, 7.2] (...)``: the sequence length recalled at that rate, 90 % interval;
        empty without counted turns."""
        rec = self.span_record()
        if rec is None:
            return ""
        head = f"span at {rec['rate']:.0%}".replace("%", " %")
        if "error" in rec:
            return f"{head}: n/a ({rec['error']})"
        rate = f"{rec['rate']:.0%}".replace("%", " %")
        return (f"{head}: {rec['median']:.1f} letters [{rec['lo']:.1f}, {rec['hi']:.1f}] (working-memory span: the "
                f"sequence length recalled {rate} of the time; 90 % interval)")

    def summary(self) -> str:
        """A plain-text summary table for the terminal."""
        lines = ["", "level  played  success rate"]
        for level, n, rate in self.level_table():
            lines.append(f"  {level}    {n:5d}    {'-' if rate is None else f'{rate:6.0%}'}")
        eng = self.mean_engagement
        invalid = len(self.invalid_rows)
        lines += [
            f"turns completed: {len(self.completed_rows)}" + (f" (+{invalid} marked invalid, not counted)" if invalid else "")
            + f"   total score: {self.total_score}" + (
                f" (valid turns only: the {invalid} marked invalid scored "
                f"{sum(int(r['score']) for r in self.invalid_rows):+d}, left out)" if invalid else "") + "   "
            f"mean engagement: {self._no_engagement() if eng is None else f'{eng:.2f}'}"
            + (f" (EEG in {self.eeg_turns} of {len(self.completed_rows)} turns)" if self.eeg_on and eng is not None else ""),
            *([span] if (span := (self.task.span(self.completed_rows) or "") if self._own_span()
                         else self.span_line()) else []),
            f"status: {self.status} (exit {self.exit_code})" + (f": {self.error}" if self.error else ""),
            *([self.summary_extra] if self.summary_extra else []),
            f"session folder: {self.path if self.path else '(none written)'}",
        ]
        if self.policy_summary:
            lines.insert(-2, self.policy_summary)
        return "\n".join(lines)


def _most_common(values: list[str]) -> str:
    return max(sorted(set(values)), key=values.count)


def progress_line(row: dict[str, Any], n_turns: int, total: int, task: Task | None = None) -> str:
    """One terminal line per recorded turn; what was presented and answered is the task's to say
    (``Task.describe``, optional: else the response pressed)."""
    fb = {0: "", 1: "  (robot feedback: encouraging)", 2: "  (robot feedback: challenging)"}[row["feedback"]]
    eng = "-" if row["engagement"] is None else f"{row['engagement']:.2f}"
    mark = "ok " if row["success"] else "err"
    describe = getattr(task, "describe", None)
    what = describe(row) if describe is not None else f"pressed {row['response'] or '-':<9}"
    return (f"turn {row['turn']:3d}/{n_turns}  L{row['level']}  {what} {mark} {row['score']:+d}  total {total:4d}  E {eng}"
            + fb + (f"  ({row['notes']})" if row["notes"] else "")
            + ("  (marked invalid: not in the total)" if row.get("invalid") else "")
            + (f"  [{row['phase']}]" if row.get("phase") else ""))

def summary_data(result: "SessionResult") -> dict[str, Any]:
    """The final summary as data (the console shows it)."""
    return {"status": result.status, "exit_code": result.exit_code, "total_score": result.total_score,
            "turns_completed": len(result.completed_rows), "mean_engagement": result.mean_engagement,
            "eeg_turns": result.eeg_turns if result.eeg_on else None, "invalid_turns": len(result.invalid_rows),
            "levels": [{"level": lv, "played": n, "success_rate": rate} for lv, n, rate in result.level_table()],
            "error": result.error, "policy_summary": result.policy_summary, "span": result.span_record()}


def span_dict(span: Span) -> dict[str, Any]:
    """A span as plain data (session.json, the console): lengths in letters, 3 decimals."""
    return {"rate": span.rate, "median": round(span.median, 3), "lo": round(span.lo, 3), "hi": round(span.hi, 3),
            "interval": span.level}


def _round(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(float(x), nd)
