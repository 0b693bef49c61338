"""EEG that survives a dropout: whole sessions over real LSL whose headband (a simulated Muse on its own
source_id) goes silent for 5 s, 20 s, or for good. The monitor reconnects by itself, the gap is in the
data, the markers and session.json, the turns it hit are flagged, and with ``eeg.turn_requires_eeg``
the turn that lost its EEG is played again as after a lost robot link.

No wall-clock bound: the session is waited for with a hang limit; the drop's length is what is tested."""
from __future__ import annotations

import csv
import json
import os
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.simulated_muse import SimulatedMuse
from nao_trainer.session import wiring as sess
from nao_trainer.session.config import load_config
from nao_trainer.session.record import read_events, read_turns

configure_lsl("machine")
HANG_S = 180.0
FAST = {"window_s": 0.5, "hop_s": 0.1, "loss_timeout_s": 0.3}


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _wait_for(probe, what: str):
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        value = probe()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what}: not within {HANG_S:g} s (a hang)")


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _session_with_a_drop(tmp_path: Path, drop_s: float | None, turns: int = 4, **over):
    """Play a session; once its first turn is recorded, the headband goes silent for ``drop_s`` seconds
    (None: its bridge dies for good). Returns the result and the folder."""
    name, sid = _uid("MuseD"), _uid("MuseDsrc")
    sim = SimulatedMuse.start(np.random.default_rng(1), name=name, source_id=sid)
    values = {"session.turns": turns, "timing.speed": 25.0, "session.output": str(tmp_path), "session.seed": 7,
              "session.practice": False, "participant.pseudonym": _uid("P").replace("-", "_"), "eeg.mode": "lsl",
              "eeg.stream_name": name, "eeg.source_id": sid, "eeg.processing": FAST, "eeg.xdf": False,
              "eeg.turn_requires_eeg": True, **over}
    cfg = load_config(None, values)
    out: dict = {}
    runner = threading.Thread(target=lambda: out.update(result=sess.run_session(cfg, sess.RunOptions(quiet=True))))
    runner.start()
    try:
        folder = _wait_for(lambda: next(tmp_path.glob("*/turns.csv"), None), "the session folder").parent
        _wait_for(lambda: len(read_turns(folder)) >= 1, "the first turn")
        if drop_s is None:
            sim.stop()  # the bridge dies: the stream is gone for good
        else:
            sim.pause()  # the headband goes silent; its stream stays announced
            time.sleep(drop_s)
            sim.resume()
        runner.join(HANG_S)
        assert not runner.is_alive(), "the session hangs"
    finally:
        sim.stop()
        runner.join(5)
    result = out["result"]
    assert result.status == "completed", result.error
    return result, folder


def _check_replayed(result, folder: Path, drop_s: float, turns: int) -> None:
    rows = read_turns(folder)
    interrupted = [r for r in rows if "interrupted: EEG lost during the listening phase" in r["notes"]]
    assert interrupted, [r["notes"] for r in rows]
    for r in interrupted:  # flagged, never silently lost, and played again under the same number
        assert "EEG lost" in r["notes"] and r["success"] == ""
        again = [q for q in rows if q["turn"] == r["turn"] and q["replay"] == "True"]
        assert again and again[-1]["success"] in ("True", "False")
    assert len([r for r in rows if r["success"] in ("True", "False")]) == turns
    info = json.loads((folder / "session.json").read_text())
    gaps = [g for g in info["eeg_gaps"] if g["duration_s"] is not None and g["duration_s"] > drop_s - 1.0]
    assert len(gaps) == 1 and not gaps[0]["until_end"], info["eeg_gaps"]  # the drop, closed; no upper bound
    assert {int(r["turn"]) for r in interrupted} <= set(gaps[0]["turns"])
    events = [e["event"] for e in read_events(folder)]
    assert "eeg_lost_in_turn" in events and "turn_interrupted" in events
    markers = [e["event"] for e in _rows(folder / "eeg" / "events.csv")]  # what the marker stream carried
    assert markers.index("eeg_stream_lost") < markers.index("eeg_stream_restored")
    assert f"turn_{interrupted[0]['turn']}_eeg_turn_replay" in markers
    assert any(float(g["duration_s"]) > drop_s - 1.0 for g in _rows(folder / "eeg" / "gaps.csv"))


@pytest.mark.slow  # ~10 s: the 5 s drop and a three-turn session
def test_a_5_s_dropout_is_a_gap_and_the_turn_it_hit_is_played_again(tmp_path):
    result, folder = _session_with_a_drop(tmp_path, 5.0, turns=3)
    _check_replayed(result, folder, 5.0, 3)


@pytest.mark.slow
def test_a_20_s_dropout_waits_for_the_stream_then_plays_the_turn_again(tmp_path):
    result, folder = _session_with_a_drop(tmp_path, 20.0, turns=3)
    _check_replayed(result, folder, 20.0, 3)
    events = read_events(folder)
    assert not any(e["event"] == "eeg_not_back" for e in events)  # waited (up to 30 s), and it came back


def test_a_stream_gone_for_good_is_waited_for_once_then_turns_are_flagged(tmp_path):
    result, folder = _session_with_a_drop(tmp_path, None, turns=4, **{"eeg.reconnect_wait_s": 1.5})
    rows = read_turns(folder)
    assert len([r for r in rows if r["success"] in ("True", "False")]) == 4
    assert not any("interrupted" in r["notes"] for r in rows)  # not back: nothing to replay with
    flagged = [r for r in rows if "EEG lost" in r["notes"]]
    assert flagged and all(r["engagement"] == "" for r in flagged)
    assert all("not replayed: the EEG stream was not back within 1.5 s" in r["notes"] for r in flagged)
    events = read_events(folder)
    assert [e["event"] for e in events].count("eeg_not_back") == 1  # waited once, not at every turn
    info = json.loads((folder / "session.json").read_text())
    last = info["eeg_gaps"][-1]
    assert last["until_end"] and last["end"] is None and set(last["turns"]) >= {int(r["turn"]) for r in flagged}
    gaps = _rows(folder / "eeg" / "gaps.csv")
    assert gaps[-1]["kind"].endswith("(until the end)") and gaps[-1]["end"] == ""


class _DropInAnswer:
    """A session observer: once turn 1's answer window is open (state ``collect``), the headband goes silent
    (after ``after_s``, past the listening phase's end) for ``drop_s`` wall seconds."""

    def __init__(self, sim, after_s: float, drop_s: float) -> None:
        self.sim, self.after_s, self.drop_s = sim, after_s, drop_s
        self.fired = threading.Event()

    def notify(self, kind, data):
        if kind == "state" and data.get("state") == "collect" and data.get("turn") == 1 and not self.fired.is_set():
            self.fired.set()
            threading.Thread(target=self._drop, daemon=True).start()

    def _drop(self):
        time.sleep(self.after_s)
        self.sim.pause()
        time.sleep(self.drop_s)
        self.sim.resume()


def test_eeg_lost_in_the_answer_phase_flags_the_turn_and_plays_it_again(tmp_path):
    """The stream stops after the listening phase ended, while the participant (nobody presses: the window
    times out) would answer on the stand-in's head over real qi: the answer phase lost EEG, so the turn is
    flagged and, with eeg.turn_requires_eeg, played again once the stream is back."""
    from nao_trainer.robot.standin import StandIn

    name, sid = _uid("MuseA"), _uid("MuseAsrc")
    sim = SimulatedMuse.start(np.random.default_rng(2), name=name, source_id=sid)
    standin = StandIn.start(speed=25)
    try:
        observer = _DropInAnswer(sim, after_s=0.15, drop_s=1.5)
        cfg = load_config(None, {
            "session.turns": 2, "timing.speed": 25.0, "session.output": str(tmp_path), "session.seed": 7,
            "session.practice": False, "participant.pseudonym": "P1", "robot.url": standin.url,
            "answers.input": "tactile", "eeg.allow_simulated": True, "timing.response_timeout_base_s": 25,
            "timing.response_timeout_per_letter_s": 0, "eeg.mode": "lsl", "eeg.stream_name": name,
            "eeg.source_id": sid, "eeg.processing": FAST, "eeg.xdf": False, "eeg.turn_requires_eeg": True})
        out: dict = {}
        runner = threading.Thread(target=lambda: out.update(
            result=sess.run_session(cfg, sess.RunOptions(quiet=True, observer=observer))))
        runner.start()
        runner.join(HANG_S)
        assert not runner.is_alive(), "the session hangs"
    finally:
        sim.stop()
        standin.stop()
    result = out["result"]
    assert result.status == "completed", result.error
    rows = read_turns(result.path)
    first = rows[0]
    assert first["turn"] == "1" and first["success"] == ""
    assert "interrupted: EEG lost during the answer phase" in first["notes"]
    assert "in the answer phase" in first["notes"] and "in the listening phase" not in first["notes"]
    again = [r for r in rows if r["turn"] == "1" and r["replay"] == "True"]
    assert again and again[-1]["success"] in ("True", "False")
    lost = [e for e in read_events(result.path) if e["event"] == "eeg_lost_in_turn"]
    assert lost[0]["turn"] == 1 and lost[0]["phase"] == "answer"
    markers = [e["event"] for e in _rows(result.path / "eeg" / "events.csv")]
    assert "turn_1_eeg_turn_replay" in markers


class _StopWhileWaiting:
    """A session observer: once the session says it waits for the lost EEG stream, the operator stops it."""

    def __init__(self, commands) -> None:
        self.commands = commands
        self.waiting = threading.Event()

    def notify(self, kind, data):
        if kind == "eeg_wait" and data.get("waiting_s") and not self.waiting.is_set():
            self.waiting.set()
            self.commands.submit("stop", source="keys")


def test_a_stop_while_the_session_waits_for_a_lost_stream_acts_at_once(tmp_path):
    """The stream is gone for good and the study would wait 600 s for it: the operator's stop (a key) ends the
    wait; the turn is recorded flagged, then the stop says goodbye (exit 5). Not honoured, the session would
    sit out the 600 s and the hang limit fails the test."""
    from nao_trainer.ports import CommandQueue
    from nao_trainer.session.engine import EXIT_OPERATOR_STOP

    name, sid = _uid("MuseW"), _uid("MuseWsrc")
    sim = SimulatedMuse.start(np.random.default_rng(3), name=name, source_id=sid)
    commands = CommandQueue()
    observer = _StopWhileWaiting(commands)
    cfg = load_config(None, {
        "session.turns": 4, "timing.speed": 25.0, "session.output": str(tmp_path), "session.seed": 7,
        "session.practice": False, "participant.pseudonym": "P1", "eeg.mode": "lsl", "eeg.stream_name": name,
        "eeg.source_id": sid, "eeg.processing": FAST, "eeg.xdf": False, "eeg.turn_requires_eeg": True,
        "eeg.reconnect_wait_s": 600})
    out: dict = {}
    runner = threading.Thread(target=lambda: out.update(
        result=sess.run_session(cfg, sess.RunOptions(quiet=True, commands=commands, observer=observer))))
    runner.start()
    try:
        folder = _wait_for(lambda: next(tmp_path.glob("*/turns.csv"), None), "the session folder").parent
        _wait_for(lambda: len(read_turns(folder)) >= 1, "the first turn")
        sim.stop()  # gone for good
        runner.join(HANG_S)
        assert not runner.is_alive(), "the session hangs: the stop was not honoured during the wait"
    finally:
        sim.stop()
    result = out["result"]
    assert result.status == "stopped" and result.exit_code == EXIT_OPERATOR_STOP, result.error
    assert observer.waiting.is_set()
    events = read_events(folder)
    cut = [e for e in events if e["event"] == "eeg_wait_cut_short"]
    assert len(cut) == 1 and cut[0]["by"] == "stop"
    assert not any(e["event"] == "eeg_not_back" for e in events)  # it did not sit the wait out
    stop = [e for e in events if e["event"] == "command" and e["kind"] == "stop"]
    assert stop and stop[0]["accepted"]
    flagged = [r for r in read_turns(folder) if "ended the wait for the EEG stream" in r["notes"]]
    assert len(flagged) == 1 and "EEG lost" in flagged[0]["notes"]
