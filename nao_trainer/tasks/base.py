"""The ``Task`` protocol: what a training task tells the session, so the session stays task-neutral.

A task defines its levels, how a trial is made from a level and a ``numpy.random.Generator``, how the trial is
presented through the robot (``Presenter``: speech, beeps, LEDs), which answer it expects and from which input,
how an answer is judged and scored, the columns it adds to a turn row, its dialogue events and its settings.
The session's states call it in order: ``present`` (``Task.present``), ``open_window`` (the beep), ``collect``
(``Trial.presses`` presses within ``Task.response_timeout_s``), ``judge`` (``Task.judge``, ``Task.score``).
A task that takes its answers while it presents (n-back) sets ``presents_in_window``: the window opens first.
Optional hooks: ``Settings`` (its ``task.settings`` class), ``describe(row)`` (the middle of the terminal's
progress line: what was presented and answered), ``dialogue_file`` (its own words), ``published_data`` (True: the fitted user models and the dataset are of this task; only the sequence task's are),
``simulated_users()`` (the population ``evaluate --task`` compares policies
on: (name, P(success) per level)), ``level_success()`` and ``simulated_answer(trial, rng,
reaction_s)`` (its own simulated participant; without them the user model's plan is used), ``table_fields``
(the row fields the supervisor console's turn table shows for it, with their headers: ``table_fields(task)``).

Levels: the MDP of the paper (``core.mdp``) has four difficulty levels and six actions; a task's ``levels`` are
those four (``core.task.LEVELS``) so every learner, planner, objective and the evaluation apply unchanged. The
turn-state label keeps the MDP's own coordinates (``core.mdp.State``); what a level *means* is the task's.
Pure: no I/O; the presenter is handed in.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping, Protocol, runtime_checkable

import numpy as np

from nao_trainer import registry
from nao_trainer.ports import Answer

#: The turns.csv columns every task has (the session writes them); a task's ``columns`` holds them all, in the
#: order the task wants, plus its own (``check_columns``).
COMMON_COLUMNS: tuple[str, ...] = (
    "turn", "start_time", "state", "level", "feedback", "previous_score", "action", "response", "success", "score",
    "signed_score", "reaction_time", "completion_time", "engagement", "engagement_index", "eeg_quality",
    "answer_engagement", "engagement_note", "notes", "invalid", "replay", "phase",
)


@dataclass(frozen=True)
class Trial:
    """One trial of a task at a level: what is presented and what answer is expected.

    ``stimuli`` are presented in order (the sequence task: its letters; n-back: its stream); ``expected`` is the
    correct answer as a tuple of button letters; ``presses`` is how many presses end the answer window early
    (None: the window runs to its timeout, the n-back stream); ``data`` holds what else the task needs.
    """

    level: int
    stimuli: tuple[str, ...]
    expected: tuple[str, ...]
    presses: int | None
    data: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Judgement:
    """An answer judged: success (the MDP's outcome), why it failed, and the task's own row fields."""

    success: bool
    notes: tuple[str, ...] = ()
    fields: Mapping[str, Any] = field(default_factory=dict)


class Presenter(Protocol):
    """What a task may ask of the robot while presenting (``session.stage.Stage`` implements it)."""

    def say(self, event: str, behavior: str | None = None, rng: np.random.Generator | None = None,
            **fields: Any) -> str: ...

    def letters(self, sequence: tuple[str, ...], turn: int | None = None) -> None: ...

    def announce(self, level: int, length: int, look: bool = True, turn: int | None = None) -> None: ...

    def beep(self, turn: int) -> float: ...

    def stream(self, stimuli: tuple[str, ...], soa_s: float, onset: float, turn: int,
               targets: tuple[bool, ...] | None = None) -> list[float]: ...

    def leds(self, rgb: int) -> None: ...


@runtime_checkable
class Task(Protocol):
    """A training task (see the module docstring). Implementations: ``tasks.sequence.SequenceTask``,
    ``tasks.nback.NBackTask``."""

    name: ClassVar[str]
    #: The difficulty levels (the MDP's four: ``core.task.LEVELS``).
    levels: ClassVar[tuple[int, ...]]
    #: Every turns.csv column, in order: ``COMMON_COLUMNS`` and the task's own.
    columns: ClassVar[tuple[str, ...]]
    #: The dialogue events the task's own presentation says (beyond the session's greeting, goodbye, ...).
    dialogue_events: ClassVar[Mapping[str, frozenset[str]]]
    #: Where the answer comes from: the head buttons (tactile), the keyboard or a simulated participant press
    #: button letters (``ports.BUTTON_LETTERS``); a task names the letters it expects.
    answer_letters: ClassVar[tuple[str, ...]]

    def make_trial(self, level: int, rng: np.random.Generator) -> Trial:
        """A new trial at ``level`` drawn with ``rng`` (the session's generator: a seed replays it)."""

    def practice_trial(self, rng: np.random.Generator) -> Trial:
        """The unscored practice round's trial."""

    def size(self, trial: Trial) -> int:
        """What ``{length}`` means in the dialogue's level announcement (letters of the trial)."""

    def present(self, stage: Presenter, trial: Trial, turn: int) -> None:
        """Play the trial through the robot (the ``present`` state). A task whose class sets
        ``presents_in_window = True`` (n-back) is presented after the window opened and is given its
        ``onset`` (monotonic seconds of the beep) as a fourth argument; the others before it."""

    def response_timeout_s(self, trial: Trial, base_s: float, per_item_s: float) -> float:
        """Session seconds the answer window stays open (the study's timing rule is handed in)."""

    def judge(self, trial: Trial, answer: Answer) -> Judgement:
        """Whether ``answer`` is a success, and the task's own fields of the row."""

    def score(self, level: int, success: bool) -> int:
        """The reward of a turn (the paper's equation (1) for the sequence task)."""

    def signed_score(self, level: int, success: bool) -> int:
        """The previous-result coordinate of the next MDP state."""

    def span(self, rows: list[dict[str, Any]]) -> str | None:
        """One line on the participant's capacity from a session's rows, None when the task has none."""


def check_columns(task: type | Task) -> tuple[str, ...]:
    """ValueError when a task's ``columns`` lacks a common column or repeats one; returns its own columns."""
    columns = tuple(task.columns)
    missing = [c for c in COMMON_COLUMNS if c not in columns]
    if missing or len(set(columns)) != len(columns):
        raise ValueError(f"task {task.name!r}: columns must hold every common column once (missing {missing})")
    return tuple(c for c in columns if c not in COMMON_COLUMNS)


#: The console's turn table shows these row fields for every task, around the task's own ``table_fields``.
TABLE_BEFORE: tuple[tuple[str, str], ...] = (("turn", "turn"), ("level", "level"), ("feedback", "fb"),
                                             ("action", "action"))
TABLE_AFTER: tuple[tuple[str, str], ...] = (("success", "ok"), ("score", "score"), ("engagement", "engagement"),
                                            ("notes", "notes"))


def table_fields(task: type | Task) -> tuple[tuple[str, str], ...]:
    """The turn-row fields the console's turn table shows for ``task``, as (row key, column header), in order:
    the common ``TABLE_BEFORE``, the task's own (its ``table_fields`` mapping, else each column it adds to
    ``COMMON_COLUMNS`` under its own name), the common ``TABLE_AFTER``. ValueError for a field not in its columns."""
    own = getattr(task, "table_fields", None)
    middle = tuple(own.items()) if own is not None else tuple((c, c.replace("_", " ")) for c in check_columns(task))
    unknown = [k for k, _ in middle if k not in task.columns]
    if unknown:
        raise ValueError(f"task {task.name!r}: table_fields {unknown} are not among its columns")
    return TABLE_BEFORE + middle + TABLE_AFTER


def published(task: Any) -> bool:
    """True when the published data, and every user model, prior and trained policy fitted on them, are ``task``'s
    (its ``published_data``: only the sequence task's are). ``task`` None (a caller that names none) is the
    sequence task."""
    return task is None or bool(getattr(task, "published_data", False))


def task_named(name: str) -> Task:
    """The registered task ``name``, built (one ``ConfigError`` line for an unknown or broken one)."""
    return registry.make("task", name)


def default_task() -> Task:
    """The task of a study that names none (``task.name``'s default, ``registry.default("task")``), built."""
    return task_named(registry.default("task"))
