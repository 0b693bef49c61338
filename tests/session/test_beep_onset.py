"""Reaction times count from the beep's onset as the robot reports it (``ports.BeepTiming``), not from
the moment the call was sent: an in-memory robot and an injected clock, so the arithmetic is exact."""
from __future__ import annotations

from fakes import FakeRobot, ScriptedAnswers
from nao_trainer.ports import BeepTiming
from nao_trainer.session.record import read_events, read_turns
from test_engine_fast import finish, make_session

NOW = 100.0  # the injected monotonic clock stands still: every delay below is the robot's


class TimedRobot(FakeRobot):
    """Its beep reports: sent at NOW, a 30 ms round trip, 40 ms from the call to the first sample."""

    def beep(self, frequency_hz, duration_s, gain=0.5):
        super().beep(frequency_hz, duration_s, gain)
        return BeepTiming(start=NOW, returned=NOW + 0.04 + duration_s + 0.015, rtt_s=0.03,
                          duration_s=duration_s, onset=NOW + 0.04)


def test_reaction_times_are_measured_from_the_reported_onset(tmp_path):
    answers = ScriptedAnswers(times=(0.5, 0.9, 1.3))
    s, rec, path, _ = make_session(tmp_path, TimedRobot(), answers, turns=1, schedule=("L1",))
    s.clock.now = lambda: NOW
    assert finish(s, rec) == 0
    (row,) = read_turns(path)
    assert float(row["reaction_time"]) == 0.46 and float(row["completion_time"]) == 1.26  # 0.5 - 0.04, 1.3 - 0.04
    beep = next(e for e in read_events(path) if e["event"] == "beep")
    assert beep["rtt_ms"] == 30.0 and beep["onset_after_call_ms"] == 40.0
    answer = next(e for e in read_events(path) if e["event"] == "answer")
    assert [p["t"] for p in answer["presses"]] == [0.46, 0.86, 1.26]


def test_a_robot_without_timing_keeps_the_call_time_as_onset(tmp_path):
    answers = ScriptedAnswers(times=(0.5, 0.9, 1.3))
    s, rec, path, _ = make_session(tmp_path, FakeRobot(), answers, turns=1, schedule=("L1",))
    s.clock.now = lambda: NOW
    assert finish(s, rec) == 0
    (row,) = read_turns(path)
    assert float(row["reaction_time"]) == 0.5


class FrozenAtTheBeep(TimedRobot):
    """The first beep's reply comes 2.5 s late (the link froze as the robot played it); the others on time."""

    late = 2.5

    def beep(self, frequency_hz, duration_s, gain=0.5):
        timing = super().beep(frequency_hz, duration_s, gain)
        late, self.late = self.late, 0.0
        return BeepTiming(timing.start, timing.returned + late, timing.rtt_s, timing.duration_s, timing.onset + late)


def test_a_beep_reply_later_than_the_link_deadline_replays_the_turn(tmp_path):
    """robot.link_deadline_s (2 s by default) is the watchdog's rule; the beep is the window's one call it
    cannot watch. Before this check the late reply opened a window 8 s late and the turn was scored."""
    answers = ScriptedAnswers(times=(0.5, 0.9, 1.3))
    s, rec, path, _ = make_session(tmp_path, FrozenAtTheBeep(), answers, turns=1, schedule=("L1",))
    s.clock.now = lambda: NOW
    assert finish(s, rec) == 0
    rows = read_turns(path)
    assert [(r["turn"], r["replay"], r["success"]) for r in rows] == [("1", "", ""), ("1", "True", "True")]
    (lost,) = [e for e in read_events(path) if e["event"] == "robot_lost"]
    assert "froze during the beep: its reply came 2.5 s late (robot.link_deadline_s is 2 s)" in lost["error"]


def test_a_beep_reply_within_the_link_deadline_is_a_slow_robot_not_a_lost_one(tmp_path):
    robot = FrozenAtTheBeep()
    robot.late = 1.9
    s, rec, path, _ = make_session(tmp_path, robot, ScriptedAnswers(times=(0.5, 0.9, 1.3)), turns=1, schedule=("L1",))
    s.clock.now = lambda: NOW
    assert finish(s, rec) == 0
    assert [r["replay"] for r in read_turns(path)] == [""]
    assert not [e for e in read_events(path) if e["event"] == "robot_lost"]
