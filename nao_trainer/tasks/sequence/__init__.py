"""The paper's sequence learning task as a ``tasks.base.Task``: hear 3/5/7/9 letters, repeat them on the buttons."""
from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from nao_trainer.core import task as levels
from nao_trainer.ports import Answer
from nao_trainer.tasks.base import Judgement, Presenter, Trial
from nao_trainer.tasks.sequence.rules import LETTERS, generate_sequence, is_correct

#: The sequence task's turns.csv, declared once (``session.record`` writes it, ``data.own`` reads it).
COLUMNS: tuple[str, ...] = (
    "turn", "start_time", "state", "length", "level", "feedback", "previous_score", "action",
    "sequence", "response", "success", "score", "signed_score", "reaction_time", "completion_time",
    "engagement", "engagement_index", "eeg_quality", "answer_engagement", "engagement_note", "notes", "invalid", "replay",
    "phase",
)


class SequenceTask:
    """Levels 1..4 = sequences of 3/5/7/9 letters; a success repeats the sequence exactly (paper section 3.1)."""

    name: ClassVar[str] = "sequence"
    levels: ClassVar[tuple[int, ...]] = levels.LEVELS
    columns: ClassVar[tuple[str, ...]] = COLUMNS
    dialogue_events: ClassVar[Mapping[str, frozenset[str]]] = {}  # the letters are spoken as they are
    answer_letters: ClassVar[tuple[str, ...]] = LETTERS
    #: The published data (the paper's sessions), the user models fitted on them and their reproductions are of
    #: this task: ``evaluate``'s fitted user sets (clusters, level-only, sessions) describe its participants.
    published_data: ClassVar[bool] = True
    #: The console's turn table: what was said and what was pressed.
    table_fields: ClassVar[Mapping[str, str]] = {"sequence": "sequence", "response": "response"}
    #: BIDS: the task label and description (``study export --bids``).
    bids_name: ClassVar[str] = "sequencelearning"
    description: ClassVar[str] = ("sequence learning task with a NAO robot (Tsiakas, Abujelala and Makedon, "
                                  "Technologies 2018, 6, 49)")

    def __init__(self, settings: Any = None) -> None:
        self.settings = settings

    def make_trial(self, level: int, rng: np.random.Generator) -> Trial:
        sequence = generate_sequence(rng, levels.length_of(level))
        return Trial(level, sequence, sequence, len(sequence))

    def practice_trial(self, rng: np.random.Generator) -> Trial:
        return self.make_trial(self.levels[0], rng)

    def size(self, trial: Trial) -> int:
        return len(trial.stimuli)

    def present(self, stage: Presenter, trial: Trial, turn: int) -> None:
        stage.letters(trial.stimuli, turn=turn)

    def response_timeout_s(self, trial: Trial, base_s: float, per_item_s: float) -> float:
        return float(base_s + per_item_s * len(trial.stimuli))

    def judge(self, trial: Trial, answer: Answer) -> Judgement:
        """Success: the exact sequence, no timeout, no invalid key; notes say why a turn failed."""
        n = len(trial.expected)
        notes: list[str] = []
        invalid = [p.key for p in answer.presses if p.letter is None]
        if not answer.presses:
            notes.append("timeout: no answer")
        elif answer.timed_out:
            notes.append(f"timeout: {len(answer.presses)} of {n} presses")
        elif len(answer.presses) > n:
            notes.append(f"too many presses: {len(answer.presses)} of {n}")
        notes += [f"invalid key {k!r}" for k in invalid]
        ok = (not answer.timed_out and len(answer.presses) == n and not invalid
              and is_correct(trial.expected, answer.response))
        return Judgement(ok, tuple(notes))

    def score(self, level: int, success: bool) -> int:
        return levels.score(level, success)

    def signed_score(self, level: int, success: bool) -> int:
        return levels.signed_score(level, success)

    def row_problem(self, row: dict[str, str]) -> str | None:
        """Why a recorded row's own fields disagree (``run --resume`` checks turns.csv): the length is the
        level's, the sequence that long, and a success repeats it."""
        try:
            level, length = int(row["level"]), int(row["length"])
        except (TypeError, ValueError, KeyError):
            return "length must be an integer"
        if length != levels.length_of(level) or len(row.get("sequence") or "") != length:
            return f"level {level}, length {length} and sequence {row.get('sequence')!r} do not agree"
        if row["success"] == "True" and not is_correct(row["sequence"], row.get("response") or ""):
            return f"success with a response {row.get('response')!r} that does not repeat the sequence {row['sequence']!r}"
        return None

    def describe(self, row: dict[str, Any]) -> str:
        """The progress line's middle: what was said vs what was pressed."""
        return f"{row['sequence']:>9} vs {row['response']:<9}"

    def span(self, rows: list[dict[str, Any]]) -> str | None:
        return None  # the session summary's span line (core.psychometric) is the sequence task's already
