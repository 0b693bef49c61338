"""The session engine's handlers against an in-memory robot (tests/fakes.py): milliseconds per session.

The same flows over real qi (the stand-in) are in test_session.py and test_session_robustness.py.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fakes import FakeRobot, ScriptedAnswers
from nao_trainer.core import mdp, task
from nao_trainer.session.behaviors import load_behaviors
from nao_trainer.session.config import load_config
from nao_trainer.session.dialogue import load_dialogue
from nao_trainer.session.engine import EXIT_INTERRUPTED, EXIT_OK, EXIT_ROBOT_LOST, Session
from nao_trainer.policies.fixed import FixedSchedule
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.session.record import SessionRecorder, read_events, read_turns


class Sleeps(list):
    """A ``sleep`` that only records (wall seconds asked for)."""

    def __call__(self, seconds: float) -> None:
        self.append(seconds)


def make_session(tmp_path: Path, robot: FakeRobot, answers: ScriptedAnswers | None = None, turns: int = 3,
                 speed: float = 1.0, practice: bool = False, schedule=("L1", "RF1", "L2"), upkeep=None, **over):
    values = {"session.turns": turns, "timing.speed": speed, "session.practice": practice,
              "session.output": str(tmp_path), "session.seed": 5, "eeg.mode": "off"}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    cfg = load_config(None, values)
    rec = SessionRecorder(tmp_path, "F")
    path = rec.open({})
    sleeps = Sleeps()
    ports = SessionPorts(robot, answers or ScriptedAnswers(), FixedSchedule(list(schedule)))
    if upkeep is not None:
        ports = dataclasses.replace(ports, upkeep=upkeep)
    session = Session(cfg, ports, rec,
                      Script(load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path)),
                      Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=None, sleep=sleeps)
    return session, rec, path, sleeps


def finish(session: Session, rec: SessionRecorder) -> int:
    code = session.run()
    rec.close(session.status, code)
    return code


def test_a_short_session_plays_every_turn_in_order(tmp_path):
    robot, answers = FakeRobot(), ScriptedAnswers(wrong={2}, simulated=True)
    s, rec, path, _ = make_session(tmp_path, robot, answers, turns=3, practice=True)
    assert finish(s, rec) == EXIT_OK and s.state == "done" and s.status == "completed"
    rows = read_turns(path)
    assert [r["action"] for r in rows] == ["L1", "RF1", "L2"]
    assert [r["success"] for r in rows] == ["True", "False", "True"]
    assert s.total == task.score(1, True) + task.score(1, False) + task.score(2, True)
    assert [int(r["state"]) for r in rows] == [mdp.encode(3, 0, 0), mdp.encode(3, 1, 1), mdp.encode(5, 0, -1)]
    assert all(r["eeg_quality"] == "" for r in rows)  # EEG off: no quality column values
    said = robot.said()
    greeting = next(e for e in read_events(path) if e["event"] == "say")
    assert greeting["what"] == "greeting" and said[0] == greeting["text"]
    # every letter of every turn (and the practice) spoken as its own plain utterance
    letters = [args[0] for name, args in robot.calls if name == "say" and args[2] == "disabled" and len(args[0]) == 1]
    assert "".join(letters) == "".join([e["sequence"] for e in read_events(path) if e["event"] == "practice"]
                                       + [r["sequence"] for r in rows])
    assert robot.count("beep") == 4 and answers.windows == 4  # practice + 3 turns
    names = [e["event"] for e in read_events(path)]
    assert names.count("simulated_plan") == 3 and names.count("turn_end") == 3
    assert robot.calls[0][0] == "go_to_posture"  # start posture before the greeting


def test_a_refused_speech_call_ends_the_session_as_a_robot_error(tmp_path):
    robot = FakeRobot()
    robot.refuse_at("beep", at=2, message="ALAudioPlayer is busy")
    s, rec, path, _ = make_session(tmp_path, robot, turns=3)
    assert finish(s, rec) == EXIT_ROBOT_LOST == 3
    assert s.status == "robot error" and "ALAudioPlayer is busy" in s.error and s.state == "aborted"
    rows = read_turns(path)
    assert [r["success"] for r in rows] == ["True", ""]  # turn 2 recorded as interrupted, not lost
    assert "interrupted: robot error" in rows[1]["notes"]
    fatal = [e for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert len(fatal) == 1 and fatal[0]["fatal"] is True


class Upkeep:
    """A ``ports.RobotUpkeep`` for a ``FakeRobot`` that goes to sleep when it refuses a call: asked after
    a refusal it finds the motors off and wakes them, the first ``wakes`` times (then it cannot)."""

    def __init__(self, robot: FakeRobot, wakes: int = 1) -> None:
        self.robot, self.wakes, self.seen = robot, wakes, 0

    def between_turns(self) -> list[str]:
        refused = sum(f.at <= self.robot.count(f.method) for f in self.robot.faults)
        asleep, self.seen = refused > self.seen, refused
        if asleep and self.wakes > 0:
            self.wakes -= 1
            return ["motors off"]
        return []


def test_a_call_refused_by_a_robot_put_to_sleep_mid_turn_is_set_back_and_the_turn_replayed(tmp_path):
    """A hand held on the head with Autonomous Life on puts NAO to sleep mid-turn and it refuses the beep:
    the session asks its upkeep, which finds the motors off and wakes them, and turn 2 is played again."""
    robot = FakeRobot()
    robot.refuse_at("beep", at=2, message="NAO is asleep")
    s, rec, path, _ = make_session(tmp_path, robot, turns=3, upkeep=Upkeep(robot))
    assert finish(s, rec) == EXIT_OK and s.status == "completed" and s.completed == 3
    rows = read_turns(path)
    assert [(r["turn"], r["replay"]) for r in rows] == [("1", ""), ("2", ""), ("2", "True"), ("3", "")]
    assert rows[1]["success"] == "" and "robot refused a call (motors off: set back)" in rows[1]["notes"]
    assert rows[2]["action"] == rows[1]["action"] and rows[2]["success"] in ("True", "False")
    failed = [e for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert len(failed) == 1 and failed[0]["fatal"] is False and failed[0]["set_back"] == ["motors off"]
    assert robot.count("beep") == 4  # turns 1, 2 (refused), 2 again, 3
    assert s.total == sum(int(r["score"]) for r in rows if r["score"])


def test_a_call_refused_by_a_robot_put_to_sleep_during_the_instructions_plays_them_again(tmp_path):
    """Asleep during the instructions (before any turn): set back, the instructions said again, the
    session plays every turn; no row is interrupted."""
    robot = FakeRobot()
    robot.refuse_at("say", at=2, message="NAO is asleep")  # 1: the greeting, 2: the instructions
    s, rec, path, _ = make_session(tmp_path, robot, turns=2, upkeep=Upkeep(robot))
    assert finish(s, rec) == EXIT_OK and s.completed == 2
    said = [e for e in read_events(path) if e["event"] == "say"]  # what the robot said (not the refused call)
    assert [e["what"] for e in said[:3]] == ["greeting", "instructions", "level"]
    assert robot.count("say") == len(said) + 1 and robot.said()[2] == said[1]["text"]  # refused, then said
    assert [r["success"] in ("True", "False") for r in read_turns(path)] == [True, True]
    (failed,) = [e for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert failed["fatal"] is False and failed["state"] == "instructions"


def test_a_refused_practice_beep_or_goodbye_is_played_again_once_set_back(tmp_path):
    """The practice's beep refused (its answer window already open): the window is abandoned and the practice
    played again. The goodbye refused after every turn is on disk: said again, the session ends completed."""
    robot, answers = FakeRobot(), ScriptedAnswers()
    robot.refuse_at("beep", at=1, message="NAO is asleep")  # the practice's beep
    s, rec, path, _ = make_session(tmp_path / "practice", robot, answers, turns=1, practice=True,
                                   upkeep=Upkeep(robot))
    assert finish(s, rec) == EXIT_OK and s.completed == 1
    assert answers.abandoned == 1 and robot.count("beep") == 3  # refused, the practice again, turn 1
    assert [e["event"] for e in read_events(path)].count("practice") == 1
    counter = FakeRobot()  # how many utterances a 1-turn session has: the last one is the goodbye
    plain, rec0, _, _ = make_session(tmp_path / "plain", counter, turns=1)
    assert finish(plain, rec0) == EXIT_OK
    robot = FakeRobot()
    robot.refuse_at("say", at=counter.count("say"), message="NAO is asleep")
    s, rec, path, _ = make_session(tmp_path / "goodbye", robot, turns=1, upkeep=Upkeep(robot))
    assert finish(s, rec) == EXIT_OK and s.status == "completed"
    assert robot.count("say") == counter.count("say") + 1  # the goodbye refused, then said
    (failed,) = [e for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert failed["state"] == "goodbye" and failed["fatal"] is False


def test_a_refused_call_with_nothing_to_set_back_or_refused_again_ends_the_session(tmp_path):
    """Upkeep cannot set anything back: a robot error as before. Set back, but the replay is refused as
    well: a robot error too (one replay per turn, never a loop)."""
    for wakes, beeps in ((0, 2), (5, 3)):
        robot = FakeRobot()
        robot.refuse_at("beep", at=2, message="busy")
        robot.refuse_at("beep", at=3, message="busy")
        s, rec, path, _ = make_session(tmp_path / str(wakes), robot, turns=3, upkeep=Upkeep(robot, wakes))
        assert finish(s, rec) == EXIT_ROBOT_LOST and s.status == "robot error"
        assert robot.count("beep") == beeps
        rows = read_turns(path)
        assert rows[0]["success"] in ("True", "False") and all(r["success"] == "" for r in rows[1:])
        assert [e["fatal"] for e in read_events(path) if e["event"] == "robot_call_failed"] == (
            [True] if wakes == 0 else [False, True])


def test_a_refused_led_or_posture_call_is_logged_and_the_session_goes_on(tmp_path):
    robot = FakeRobot()
    robot.refuse_at("set_eye_leds", at=3)
    robot.refuse_at("go_to_posture", at=1)
    s, rec, path, _ = make_session(tmp_path, robot, turns=2)
    assert finish(s, rec) == EXIT_OK
    failed = [e["what"] for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert sorted(failed) == ["leds", f"posture {s.behaviors.start_posture}"]
    assert len(read_turns(path)) == 2


def test_a_programming_error_is_not_a_robot_error(tmp_path):
    class Broken(ScriptedAnswers):
        def collect(self, n_expected, timeout_s):
            raise ValueError("collect() before prepare()")

    s, rec, _, _ = make_session(tmp_path, FakeRobot(), Broken(), turns=1)
    with pytest.raises(ValueError, match="before prepare"):
        s.run()
    rec.close("error", 1)
    assert s.status == "running"  # not turned into "robot error" / exit 3


def test_a_lost_robot_is_reconnected_and_the_turn_replayed(tmp_path):
    robot = FakeRobot(reconnect_after=2)
    robot.lose_at("beep", at=2)  # during turn 2
    answers = ScriptedAnswers()
    s, rec, path, sleeps = make_session(tmp_path, robot, answers, turns=3, robot__backoff_initial_s=0.25,
                                        timing__pause_before_level_s=0, timing__letter_gap_s=0,
                                        timing__listening_tail_s=0)
    assert finish(s, rec) == EXIT_OK and s.completed == 3
    rows = read_turns(path)
    assert [r["turn"] for r in rows] == ["1", "2", "2", "3"]
    assert rows[1]["success"] == "" and "robot lost during open_window" in rows[1]["notes"]
    assert rows[2]["notes"] == "replay of interrupted turn" and rows[2]["action"] == rows[1]["action"]
    assert rows[2]["state"] == rows[1]["state"] and rows[2]["sequence"] != ""
    assert [r["replay"] for r in rows] == ["", "", "True", ""]  # the replay says so in a column
    assert robot.reconnect_attempts == 2 and answers.abandoned == 1
    assert sleeps == [0.25, 0.5]  # exponential backoff in wall seconds (not scaled by the speed)
    events = [e["event"] for e in read_events(path)]
    assert events.index("robot_lost") < events.index("reconnected") < events.index("turn_interrupted") + 10
    assert [e for e in read_events(path) if e["event"] == "say" and e["what"] == "resumed"]


def test_a_robot_that_stays_away_ends_the_session_with_exit_3(tmp_path):
    robot = FakeRobot(reconnect_after=0)
    robot.lose_at("say", at=4)
    s, rec, path, _ = make_session(tmp_path, robot, turns=2, robot__max_reconnect_s=0)
    assert finish(s, rec) == EXIT_ROBOT_LOST and s.status == "robot lost" and s.state == "aborted"
    assert "give_up" in [e["event"] for e in read_events(path)]


def test_ctrl_c_aborts_with_130_and_records_the_turn_in_flight(tmp_path):
    robot = FakeRobot()
    robot.interrupt_at("beep", at=2)
    s, rec, path, _ = make_session(tmp_path, robot, turns=3)
    assert finish(s, rec) == EXIT_INTERRUPTED == 130
    assert s.status == "interrupted" and s.state == "aborted"
    assert robot.count("stop_all") == 1  # silenced before the safe posture
    rows = read_turns(path)
    assert len(rows) == 2 and rows[1]["notes"] == "interrupted: operator (Ctrl-C)"
    s.leave_safe()
    assert robot.calls[-2][0] == "go_to_posture" and robot.calls[-1][0] == "set_eye_leds"


def test_the_clock_scales_every_wait_by_the_speed(tmp_path):
    speed = 10.0
    robot = FakeRobot()
    answers = ScriptedAnswers(times=(0.1, 0.2, 0.3))
    s, rec, path, sleeps = make_session(tmp_path, robot, answers, turns=1, speed=speed, schedule=("L1",),
                                        timing__listening_tail_s=0.0)
    assert finish(s, rec) == EXIT_OK
    t = s.cfg.timing
    # pause before the level, then two gaps between the three letters (session seconds / speed)
    assert sleeps == pytest.approx([t.pause_before_level_s / speed] + [t.letter_gap_s / speed] * 2)
    beep = next(args for name, args in robot.calls if name == "beep")
    assert beep == (t.beep_hz, pytest.approx(t.beep_s / speed), t.beep_gain)
    fades = [args[1] for name, args in robot.calls if name == "set_eye_leds"]
    assert fades and fades == pytest.approx([s.behaviors.led_fade_s / speed] * len(fades))
    assert answers.timeouts == [pytest.approx(t.response_timeout_s(3) / speed)]
    row = read_turns(path)[0]
    # recorded in session seconds from the beep; the beep is called after the window opens (where the scripted
    # times start), so a busy machine that delays the call can only shorten it (0.959 for 1.0 was seen)
    for column, scripted in (("reaction_time", 0.1), ("completion_time", 0.3)):
        assert scripted * speed - 0.5 <= float(row[column]) <= scripted * speed + 1e-9, row


def test_events_hold_every_utterance_and_each_press_with_its_time(tmp_path):
    """The level announcements and the letters are in events.jsonl too, and every press with its time."""
    robot, answers = FakeRobot(), ScriptedAnswers(wrong={2})
    s, rec, path, _ = make_session(tmp_path, robot, answers, turns=2, practice=True, speed=4.0)
    assert finish(s, rec) == EXIT_OK
    events = read_events(path)
    assert [e["text"] for e in events if e["event"] == "say"] == robot.said()  # all of them, in order
    letters = [e for e in events if e["event"] == "say" and e["what"] == "letter"]
    rows = read_turns(path)
    assert "".join(e["text"] for e in letters if e["turn"] == 1) == rows[0]["sequence"]
    answers_logged = {e["turn"]: e for e in events if e["event"] == "answer"}
    assert sorted(answers_logged) == [0, 1, 2]  # the practice too
    for row in rows:
        logged = answers_logged[int(row["turn"])]
        assert "".join(p["letter"] for p in logged["presses"]) == row["response"]
        assert [p["t"] for p in logged["presses"]] == [round(0.1 * 4 * (i + 1), 3) for i in range(len(row["response"]))]
        assert logged["presses"][0]["t"] == float(row["reaction_time"])
