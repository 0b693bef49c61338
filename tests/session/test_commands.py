"""Operator commands through the one command path (ports.CommandQueue), against the in-memory robot.

Pause, resume, stop, override, repeat, mark invalid and note act at the engine's defined points,
through the state machine, and are recorded in events.jsonl with their time and source.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fakes import FakeRobot, ScriptedAnswers
from nao_trainer.core import mdp
from nao_trainer.ports import CommandQueue, NullMonitor, Transition
from nao_trainer.session.behaviors import load_behaviors
from nao_trainer.session.config import load_config
from nao_trainer.session.dialogue import load_dialogue
from nao_trainer.session.engine import EXIT_OK, EXIT_OPERATOR_STOP, Session
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.session.machine import TRANSITIONS
from nao_trainer.policies.fixed import FixedSchedule
from nao_trainer.session.record import SessionRecorder, read_events, read_turns

PAUSE_LINE = "Sorry, I need a short break. Please wait a moment."


class HookedRobot(FakeRobot):
    """A FakeRobot that runs ``hooks[text]`` when it is asked to say ``text`` (the n-th time when listed)."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.hooks: dict[str, list] = {}

    def say(self, text, animated=False, mode="contextual"):
        super().say(text, animated, mode)
        todo = self.hooks.get(text)
        if todo:
            todo.pop(0)()


class MarkingMonitor(NullMonitor):
    def __init__(self):
        self.marks: list[str] = []

    def mark(self, event, turn=None):
        self.marks.append(event)


class CountingSchedule(FixedSchedule):
    def __init__(self, actions):
        super().__init__(actions)
        self.observed: list[Transition] = []

    def observe(self, transition):
        self.observed.append(transition)


class FakeTime:
    """Sleeps advance a fake monotonic clock (so session durations are exact)."""

    def __init__(self):
        self.t = 1000.0

    def sleep(self, s):
        self.t += s

    def now(self):
        return self.t


def make(tmp_path: Path, robot=None, answers=None, turns=3, schedule=("L1", "L2", "L3"), policy=None, **over):
    values = {"session.turns": turns, "timing.speed": 1.0, "session.practice": False, "session.output": str(tmp_path),
              "session.seed": 5, "eeg.mode": "off"}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    cfg = load_config(None, values)
    rec = SessionRecorder(tmp_path, "F")
    path = rec.open({})
    queue = CommandQueue()
    monitor = MarkingMonitor()
    clock = FakeTime()
    ports = SessionPorts(robot or HookedRobot(), answers or ScriptedAnswers(),
                         policy or CountingSchedule(list(schedule)), monitor, queue)
    s = Session(cfg, ports, rec, Script(load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path)),
                Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=None, sleep=clock.sleep)
    s.clock.now = clock.now
    return s, rec, path, queue, monitor


def run(s, rec):
    code = s.run()
    rec.close(s.status, code)
    return code


def commands(path):
    return [e for e in read_events(path) if e["event"] == "command"]


def test_pause_mid_turn_says_the_pause_line_waits_and_resume_replays_the_turn(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, monitor = make(tmp_path, robot)
    robot.hooks["Level 2."] = [lambda: q.submit("pause", source="keys")]  # during turn 2's announcement
    robot.hooks[PAUSE_LINE] = [lambda: q.submit("resume", source="console")]
    assert run(s, rec) == EXIT_OK and s.status == "completed"
    rows = read_turns(path)
    assert [r["turn"] for r in rows] == ["1", "2", "2", "3"]
    assert rows[1]["success"] == "" and rows[1]["notes"] == "interrupted: pause by operator (keys)"
    assert rows[2]["notes"] == "replay of interrupted turn" and rows[2]["action"] == rows[1]["action"] == "L2"
    said = robot.said()
    i = said.index(PAUSE_LINE)
    assert said[i - 1] == "Level 2." and "I am back" in said[i + 1]  # the utterance finished, then the pause line
    cmds = commands(path)
    assert [(c["kind"], c["source"], c["accepted"]) for c in cmds] == [("pause", "keys", True), ("resume", "console", True)]
    assert all(c["at"] and c["t"] for c in cmds)
    moves = [(e["trigger"], e.get("reason")) for e in read_events(path) if e["event"] == "transition"]
    assert ("pause", "pause by operator (keys)") in moves and ("resume_turn", "resume by operator (console)") in moves
    assert {"command_pause", "pause_start", "pause_end", "command_resume"} <= set(monitor.marks)
    assert monitor.marks.index("pause_start") < monitor.marks.index("pause_end")


def test_stop_says_goodbye_and_exits_with_the_operator_stop_code(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, _ = make(tmp_path, robot, turns=5)
    robot.hooks["Level 2."] = [lambda: q.submit("stop", source="console")]
    assert run(s, rec) == EXIT_OPERATOR_STOP == 5
    assert s.status == "stopped" and s.state == "done"
    rows = read_turns(path)
    assert len(rows) == 2 and rows[1]["success"] == "" and "stop by operator (console)" in rows[1]["notes"]
    assert "Thank you" in robot.said()[-1]  # the goodbye
    s.leave_safe()
    assert robot.calls[-2] == ("go_to_posture", (s.behaviors.safe_posture, s.cfg.robot.posture_speed))


def test_override_plays_the_chosen_action_and_the_policy_learns_from_it(tmp_path):
    s, rec, path, q, _ = make(tmp_path, turns=3)
    q.submit("override", {"action": "L4"}, source="console")  # before the session starts: used for turn 1
    assert run(s, rec) == EXIT_OK
    rows = read_turns(path)
    assert [r["action"] for r in rows] == ["L4", "L1", "L2"]  # the schedule goes on from where it was
    assert rows[0]["notes"] == "operator chose L4" and rows[0]["level"] == "4"
    assert s.ports.policy.observed[0].action == mdp.ACTION_NAMES.index("L4")  # off-policy: the played action is learned


def test_an_override_not_allowed_in_the_state_is_refused_and_the_policy_plays(tmp_path):
    s, rec, path, q, _ = make(tmp_path, turns=1)
    q.submit("override", {"action": "RF1"})  # no feedback before the first turn
    q.submit("override", {"action": "L9"})
    assert run(s, rec) == EXIT_OK
    assert read_turns(path)[0]["action"] == "L1"
    assert [e for e in read_events(path) if e["event"] == "command_refused"][0]["action"] == "RF1"
    assert [c["accepted"] for c in commands(path)] == [True, False]


def test_mark_invalid_keeps_the_row_and_the_learner_does_not_see_the_turn(tmp_path):
    answers = ScriptedAnswers()
    s, rec, path, q, _ = make(tmp_path, answers=answers, turns=3)
    answers.on_collect = lambda ctx: ctx.turn == 2 and q.submit("invalid", {"turn": 2, "note": "door opened"}, "console")
    assert run(s, rec) == EXIT_OK
    rows = read_turns(path)
    assert [r["invalid"] for r in rows] == ["", "True", ""]
    assert rows[1]["success"] == "True" and "invalid (console): door opened" in rows[1]["notes"]
    assert [t.action for t in s.ports.policy.observed] == [0, 2]  # turns 1 and 3 only
    assert any(e["event"] == "not_learned" and e["turn"] == 2 for e in read_events(path))
    # the running total (turn lines, goodbye, checkpoints) counts what the summary counts (issue 29)
    assert s.total == sum(int(r["score"]) for r in rows if r["invalid"] != "True")


def test_a_recorded_turn_cannot_be_marked_invalid(tmp_path):
    answers = ScriptedAnswers()
    s, rec, path, q, _ = make(tmp_path, answers=answers, turns=3)
    answers.on_collect = lambda ctx: ctx.turn == 3 and q.submit("invalid", {"turn": 1})
    run(s, rec)
    c = commands(path)[0]
    assert not c["accepted"] and "not the turn in flight" in c["detail"]
    assert all(r["invalid"] == "" for r in read_turns(path))


def test_repeat_between_turns_replays_the_last_action_and_mid_turn_replays_the_turn(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, _ = make(tmp_path, robot, turns=4, schedule=("L1", "L2", "L3", "L4"))
    answers = s.ports.answers
    answers.on_collect = lambda ctx: ctx.turn == 1 and q.submit("repeat")  # held until turn 1 is recorded
    robot.hooks["Level 2."] = [lambda: q.submit("repeat")]  # turn 3 (L2) in flight
    assert run(s, rec) == EXIT_OK
    rows = read_turns(path)
    assert [(r["turn"], r["action"]) for r in rows] == [("1", "L1"), ("2", "L1"), ("3", "L2"), ("3", "L2"), ("4", "L3")]
    assert rows[2]["success"] == "" and "repeat by operator" in rows[2]["notes"]


def test_notes_and_refused_commands_are_recorded_with_source_and_reason(tmp_path):
    s, rec, path, q, _ = make(tmp_path, turns=1)
    q.submit("note", {"text": "participant asked for water"}, source="console")
    q.submit("resume", source="keys")  # not paused
    assert run(s, rec) == EXIT_OK
    note, resume = commands(path)
    assert note["accepted"] and note["detail"] == "participant asked for water" and note["source"] == "console"
    assert not resume["accepted"] and resume["detail"] == "not possible in state greet"
    moves = [e for e in read_events(path) if e["event"] == "transition"]
    assert moves[0]["trigger"] == "add_note" and moves[0]["dest"] == "greet" and moves[0]["internal"] is True
    assert moves[0]["reason"] == "note by operator (console)"
    with pytest.raises(ValueError, match="unknown command"):
        q.submit("dance")


def test_max_duration_ends_the_session_cleanly_between_turns(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, _ = make(tmp_path, robot, turns=20, session__max_duration_s=5.0)
    assert run(s, rec) == EXIT_OK and s.status == "time limit" and s.state == "done"
    rows = read_turns(path)
    assert 1 <= len(rows) < 20 and all(r["success"] in ("True", "False") for r in rows)  # no turn cut short
    ev = [e for e in read_events(path) if e["event"] == "max_duration"]
    assert ev and ev[0]["elapsed_s"] >= 5.0
    assert "Thank you" in robot.said()[-1]


def test_pause_in_the_introduction_resumes_with_the_instructions(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, _ = make(tmp_path, robot, turns=1)
    q.submit("pause")
    robot.hooks[PAUSE_LINE] = [lambda: q.submit("resume")]
    assert run(s, rec) == EXIT_OK
    triggers = [e["trigger"] for e in read_events(path) if e["event"] == "transition"]
    assert triggers[:2] == ["pause", "resume_intro"]


def test_every_command_kind_has_a_transition_in_the_table():
    from nao_trainer.ports import COMMAND_KINDS
    from nao_trainer.session.machine import COMMAND_TRIGGERS

    names = {t["trigger"] for t in TRANSITIONS}
    assert set(COMMAND_TRIGGERS) == set(COMMAND_KINDS)
    assert all(t in names for ts in COMMAND_TRIGGERS.values() for t in ts)


def test_commands_sent_together_act_one_state_change_at_a_time(tmp_path):
    robot = HookedRobot()
    s, rec, path, q, _ = make(tmp_path, robot, turns=3)

    def burst():
        q.submit("pause", source="console")
        q.submit("note", {"text": "after the pause"}, source="console")
        q.submit("resume", source="console")

    robot.hooks["Level 2."] = [burst]
    assert run(s, rec) == EXIT_OK
    cmds = commands(path)
    assert [(c["kind"], c["state"], c["accepted"]) for c in cmds] == [
        ("pause", "present", True), ("note", "operator_pause", True), ("resume", "operator_pause", True)]
    assert robot.said().count(PAUSE_LINE) == 1 and len([r for r in read_turns(path) if r["success"]]) == 3


def test_a_malformed_command_is_refused_and_logged_and_the_session_goes_on(tmp_path):
    # issue 18: {"turn": "abc"} reached int() in the session thread and ended the session (exit 1)
    answers = ScriptedAnswers()
    s, rec, path, q, _ = make(tmp_path, answers=answers, turns=3)
    answers.on_collect = lambda ctx: ctx.turn == 2 and [q.submit("invalid", {"turn": bad}, "api")
                                                         for bad in ("abc", [1], float("inf"))]
    assert run(s, rec) == EXIT_OK
    refused = commands(path)
    assert [c["accepted"] for c in refused] == [False, False, False]
    assert all("malformed arguments ignored" in c["detail"] for c in refused)
    assert [r["turn"] for r in read_turns(path)] == ["1", "2", "3"] and all(r["invalid"] == "" for r in read_turns(path))
