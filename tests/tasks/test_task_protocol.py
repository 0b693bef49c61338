"""The Task protocol and the sequence task behind it (issue 26 item 2)."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer import registry
from nao_trainer.errors import ConfigError
from nao_trainer.ports import Answer, Press
from nao_trainer.session import machine
from nao_trainer.session.config import load_config
from nao_trainer.session.record import TURN_COLUMNS
from nao_trainer.tasks.base import COMMON_COLUMNS, TABLE_AFTER, TABLE_BEFORE, Task, check_columns, table_fields, task_named
from nao_trainer.tasks.sequence import SequenceTask, rules


def test_sequence_task_is_registered_and_is_a_task():
    task = task_named("sequence")
    assert isinstance(task, SequenceTask) and isinstance(task, Task)
    assert registry.spec("task", "sequence").entry_point == "nao_trainer.tasks.sequence:SequenceTask"
    assert check_columns(task) == ("length", "sequence")
    assert TURN_COLUMNS == task.columns  # the schema is declared once, by the task


def test_sequence_trials_draw_as_the_session_always_did():
    task = SequenceTask()
    for level, length in zip(task.levels, (3, 5, 7, 9)):
        a, b = np.random.default_rng(level), np.random.default_rng(level)
        trial = task.make_trial(level, a)
        assert trial.stimuli == rules.generate_sequence(b, length) == trial.expected and trial.presses == length


def test_sequence_judge_names_why_a_turn_failed():
    task = SequenceTask()
    trial = task.make_trial(1, np.random.default_rng(0))
    right = Answer(tuple(Press(x, x, 0.1 * i) for i, x in enumerate(trial.stimuli)), False)
    assert task.judge(trial, right).success
    late = Answer(right.presses[:2], True)
    assert task.judge(trial, late) == task.judge(trial, late) and not task.judge(trial, late).success
    assert task.judge(trial, late).notes == ("timeout: 2 of 3 presses",)
    bad = Answer((*right.presses[:2], Press("x", None, 0.3)), False)
    assert task.judge(trial, bad).notes == ("invalid key 'x'",)


def test_turn_states_are_task_neutral_and_grouped_by_name():
    assert machine.TURN_STATES == ("select_action", "feedback", "announce", "present", "open_window", "collect",
                                   "judge", "record")
    assert set(machine.IN_TURN) == set(machine.TURN_STATES) - {"select_action"}
    assert set(machine.REPLAYABLE) == set(machine.IN_TURN) - {"judge", "record"}
    assert "judge" not in machine.INTERRUPTIBLE and "present" in machine.INTERRUPTIBLE
    for group in (machine.IN_TURN, machine.REPLAYABLE, machine.INTERRUPTIBLE):
        assert set(group) <= set(machine.STATES)


def test_task_section_resolves_through_the_registry(tmp_path):
    assert load_config(None).task.name == "sequence"
    with pytest.raises(ConfigError, match=r"unknown task 'sequense' \(did you mean 'sequence'\?\)"):
        load_config(None, {"task.name": "sequense"})
    with pytest.raises(ConfigError, match="task 'sequence' has no settings"):
        load_config(None, {"task.settings": {"x": 1}}).task.build_task()


def test_common_columns_are_in_every_builtin_task():
    for name in registry.names("task"):
        cls = registry.load("task", name)
        assert set(COMMON_COLUMNS) <= set(cls.columns), name


def test_the_consoles_turn_table_takes_its_fields_from_the_task():
    """Issue 26: the console shows a task's own row fields (``table_fields``), else the columns it adds."""
    assert table_fields(SequenceTask) == TABLE_BEFORE + (("sequence", "sequence"), ("response", "response")) + TABLE_AFTER
    nback = dict(table_fields(registry.load("task", "nback")))
    assert nback["false_alarms"] == "false alarms" and nback["d_prime"] == "d′" and "sequence" not in nback

    class Plain:  # a plug-in task that declares no table fields: its own columns, under their names
        name, columns = "plain", COMMON_COLUMNS + ("letters", "correct_positions")

    assert table_fields(Plain)[len(TABLE_BEFORE):-len(TABLE_AFTER)] == (("letters", "letters"),
                                                                       ("correct_positions", "correct positions"))

    class Wrong(Plain):
        name, table_fields = "wrong", {"letters": "letters", "sequence": "sequence"}

    with pytest.raises(ValueError, match=r"task 'wrong': table_fields \['sequence'\] are not among its columns"):
        table_fields(Wrong)
