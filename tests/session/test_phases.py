"""session.phases: EEG lost mid-session is told to the operator after ``eeg.missing_alert_turns`` turns in a row."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from fakes import FakeRobot, ScriptedAnswers
from nao_trainer.ports import NullMonitor, PhaseEngagement
from nao_trainer.session.behaviors import load_behaviors
from nao_trainer.session.config import load_config
from nao_trainer.session.dialogue import load_dialogue
from nao_trainer.session.engine import Session
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.policies.fixed import FixedSchedule
from nao_trainer.session.record import SessionRecorder, read_events


class LostAfter(NullMonitor):
    """A headband that gives engagement for the first ``good`` listening phases, then nothing (stream lost)."""

    records_eeg = True

    def __init__(self, good: int) -> None:
        self.good, self.listening, self.phase = good, 0, ""

    def begin_phase(self, phase, turn):
        self.phase = phase

    def end_phase(self):
        if self.phase != "listening":
            return PhaseEngagement(None, None, 0.0, "not listening")
        self.listening += 1
        if self.listening <= self.good:
            return PhaseEngagement(0.8, 1.2, 1.0)
        return PhaseEngagement(None, None, 0.0, "EEG stream lost")


class Seen(list):
    def notify(self, kind, data):
        self.append((kind, data))


def play(tmp_path: Path, monitor: LostAfter, turns: int, **over) -> tuple[Path, str, Seen]:
    values = {"session.turns": turns, "session.practice": False, "session.output": str(tmp_path), "session.seed": 5,
              "eeg.mode": "off", **over}
    cfg = load_config(None, values)
    rec = SessionRecorder(tmp_path, "E")
    path = rec.open({})
    progress, seen = io.StringIO(), Seen()
    session = Session(cfg, SessionPorts(FakeRobot(), ScriptedAnswers(), FixedSchedule(["L1"]), monitor, observer=seen),
                      rec, Script(load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path)),
                      Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=progress,
                      sleep=lambda s: None)
    assert session.run() == 0
    rec.close(session.status, 0)
    return path, progress.getvalue(), seen


def test_the_operator_is_told_once_when_eeg_is_missing_for_several_turns(tmp_path):
    path, progress, seen = play(tmp_path, LostAfter(good=1), turns=8)
    alerts = [e for e in read_events(path) if e["event"] == "eeg_missing"]
    assert len(alerts) == 1 and alerts[0]["turn"] == 4 and alerts[0]["turns"] == 3  # turns 2, 3, 4 without EEG
    assert alerts[0]["reason"] == "EEG stream lost"
    lines = [ln for ln in progress.splitlines() if "no EEG" in ln]
    assert lines == ["warning: no EEG for the last 3 turns (EEG stream lost): check the headband and its stream"]
    assert [d for k, d in seen if k == "eeg"] == [{"missing_turns": 3, "turn": 4, "reason": "EEG stream lost"}]


def test_the_alert_threshold_is_configurable_and_zero_turns_it_off(tmp_path):
    path, _, _ = play(tmp_path / "a", LostAfter(good=0), turns=3, **{"eeg.missing_alert_turns": 2})
    assert [e["turn"] for e in read_events(path) if e["event"] == "eeg_missing"] == [2]
    path, progress, _ = play(tmp_path / "b", LostAfter(good=0), turns=3, **{"eeg.missing_alert_turns": 0})
    assert not [e for e in read_events(path) if e["event"] == "eeg_missing"] and "no EEG" not in progress
