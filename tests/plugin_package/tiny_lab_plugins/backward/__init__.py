"""The task ``backward``: the robot says 2/3/4/5 letters, the participant presses them on the head buttons in
reverse order (a backward letter span). A lab's own task in its own folder: rules, row fields, settings, its
simulated participant and its words (``en.yaml``), registered by the entry point ``nao_trainer.tasks``.

Everything it needs from nao-trainer is public: the ``Task`` protocol's data types (``tasks.base``), the MDP's
levels and reward (``core.task``), the settings declaration (``core.settings``) and ``ports.Answer``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from nao_trainer.core import task as mdp_levels
from nao_trainer.core.settings import setting, settings
from nao_trainer.ports import Answer
from nao_trainer.tasks.base import COMMON_COLUMNS, Judgement, Presenter, Trial

LETTERS: tuple[str, ...] = ("A", "B", "C")  # the three head buttons (front, middle, rear)
LENGTHS: tuple[int, ...] = (2, 3, 4, 5)  # letters at levels 1..4
#: The task's own turns.csv columns, after the common ones.
OWN_COLUMNS: tuple[str, ...] = ("letters", "expected", "correct_positions")


def _four_rates(value: Any) -> str | None:
    if not isinstance(value, list) or len(value) != 4 or not all(isinstance(v, (int, float)) and 0 <= v <= 1
                                                                 for v in value):
        return f"must be 4 probabilities (levels 1..4), got {value!r}"
    return None


@settings
class BackwardSettings:
    """The task's own keys (``task.settings``)."""

    seconds_per_letter: float = setting(2.5, kind=(int, float), above=0.0, max=20.0,
                                        doc="answer window: seconds per letter after the beep")
    success_by_level: list = setting(factory=lambda: [0.9, 0.7, 0.45, 0.2], kind=list, check=_four_rates,
                                     doc="simulated participant: P(all letters reversed right) at levels 1..4")


class BackwardTask:
    """Backward letter span on the head buttons (a lab's plug-in)."""

    name: ClassVar[str] = "backward"
    levels: ClassVar[tuple[int, ...]] = mdp_levels.LEVELS
    columns: ClassVar[tuple[str, ...]] = COMMON_COLUMNS + OWN_COLUMNS
    dialogue_events: ClassVar[Mapping[str, frozenset[str]]] = {}
    answer_letters: ClassVar[tuple[str, ...]] = LETTERS
    Settings: ClassVar[type] = BackwardSettings
    dialogue_file: ClassVar[Path] = Path(__file__).parent / "en.yaml"

    def __init__(self, settings: BackwardSettings | None = None) -> None:
        self.settings = settings or BackwardSettings()

    def make_trial(self, level: int, rng: np.random.Generator) -> Trial:
        letters = tuple(LETTERS[i] for i in rng.integers(0, len(LETTERS), size=LENGTHS[level - 1]))
        return Trial(level, letters, letters[::-1], len(letters))

    def practice_trial(self, rng: np.random.Generator) -> Trial:
        return self.make_trial(1, rng)

    def size(self, trial: Trial) -> int:
        return len(trial.stimuli)

    def present(self, stage: Presenter, trial: Trial, turn: int) -> None:
        stage.letters(trial.stimuli, turn=turn)

    def response_timeout_s(self, trial: Trial, base_s: float, per_item_s: float) -> float:
        return float(base_s + self.settings.seconds_per_letter * len(trial.stimuli))

    def judge(self, trial: Trial, answer: Answer) -> Judgement:
        response = tuple(answer.response)
        right = sum(a == b for a, b in zip(response, trial.expected))
        ok = not answer.timed_out and response == trial.expected
        notes = () if ok else (f"{right} of {len(trial.expected)} in reverse order",)
        return Judgement(ok, notes, {"letters": "".join(trial.stimuli), "expected": "".join(trial.expected),
                                     "correct_positions": right})

    def score(self, level: int, success: bool) -> int:
        return mdp_levels.score(level, success)

    def signed_score(self, level: int, success: bool) -> int:
        return mdp_levels.signed_score(level, success)

    def span(self, rows: list[dict[str, Any]]) -> str | None:
        won = [LENGTHS[int(r["level"]) - 1] for r in rows if str(r.get("success")) in ("True", "true", "1")]
        return f"longest backward span: {max(won)} letters" if won else "longest backward span: none yet"

    # -- its simulated participant ---------------------------------------------------------------------------

    def level_success(self) -> tuple[float, ...]:
        return tuple(float(p) for p in self.settings.success_by_level)

    def simulated_answer(self, trial: Trial, rng: np.random.Generator,
                         reaction_s: float) -> tuple[bool, tuple[str, ...], tuple[float, ...], str]:
        """(intended success, letters, seconds after the beep, note): right with the level's probability, else
        the letters as heard (the usual mistake: forgetting to reverse)."""
        ok = bool(rng.random() < self.settings.success_by_level[trial.level - 1])
        letters = trial.expected if ok or trial.stimuli == trial.expected else trial.stimuli
        ok = letters == trial.expected
        times = tuple(reaction_s + 0.6 * i for i in range(len(letters)))
        return ok, letters, times, "" if ok else "not reversed"
