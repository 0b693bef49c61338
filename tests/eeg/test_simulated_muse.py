"""The simulated Muse and the replay of published raw sessions, over real LSL streams (machine scope)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from nao_trainer.core.engagement import engagement_index, relative_band_powers
from nao_trainer.eeg.inlet import EEGInlet, StreamQuery, resolve_eeg
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.simulated_muse import (MUSE_LABELS, MuseSignal, ReplayMuse, SimulatedMuse, load_raw_session,
                                            target_ratio)
from nao_trainer.errors import DataError
from nao_trainer.data.published import read_recording

configure_lsl("machine")


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _index_of(x: np.ndarray, fs: float = 256.0) -> float:
    bands = relative_band_powers(x[:, :4], fs).mean(axis=0)
    return float(engagement_index(*bands))


def test_signal_engagement_rises_with_target():
    indices = []
    for target in (0.0, 0.25, 0.5, 0.75, 1.0):
        sig = MuseSignal(np.random.default_rng(7), target=target)
        sig.next(256)  # let the power mix settle at the target
        indices.append(_index_of(sig.next(4 * 256)))
    assert np.all(np.diff(indices) > 0), indices
    assert indices[-1] > 3 * indices[0]
    assert target_ratio(0.0) < target_ratio(0.5) < target_ratio(1.0)


def test_signal_is_seeded_and_continuous():
    a, b = MuseSignal(np.random.default_rng(3)), MuseSignal(np.random.default_rng(3))
    xa = np.concatenate([a.next(12) for _ in range(20)])
    xb = np.concatenate([b.next(12) for _ in range(20)])
    assert np.array_equal(xa, xb)
    assert xa.shape == (240, 5)
    # consecutive chunks join without jumps: the largest step stays within a plausible EEG range
    assert np.abs(np.diff(xa[:, :4], axis=0)).max() < 60
    with pytest.raises(ValueError, match="target engagement"):
        a.set_target(1.5)


def test_signal_faults():
    sig = MuseSignal(np.random.default_rng(0))
    sig.faults = {1: "flat", 2: "saturated"}
    x = sig.next(256)
    assert np.ptp(x[:, 1]) == 0
    assert (x[:, 2] == 1000.0).mean() > 0.9 and np.ptp(x[:, 2]) > 100


def test_inlet_finds_simulated_muse_and_drops_aux():
    sid = _uid("MuseTest")
    with SimulatedMuse.start(np.random.default_rng(1), target=0.8, source_id=sid) as sim:
        info = resolve_eeg(StreamQuery("EEG", source_id=sid), 5.0)
        assert info is not None and info.name() == "Muse"
        inlet = EEGInlet.open(info)
        try:
            assert inlet.labels == MUSE_LABELS
            assert inlet.scalp_labels == ("TP9", "AF7", "AF8", "TP10")
            assert inlet.scalp_index == (0, 1, 2, 3)
            assert inlet.fs == 256.0 and inlet.source_id == sid
            got, stamps = [], []
            deadline = time.monotonic() + 5
            while sum(len(s) for s in stamps) < 256 and time.monotonic() < deadline:
                x, ts = inlet.pull(0.2)
                got.append(x)
                stamps.append(ts)
            x, ts = np.concatenate(got), np.concatenate(stamps)
            assert x.shape[1] == 4 and len(ts) >= 256
            import pylsl

            # on this machine's LSL clock, not wall-clock time (which differs by decades of seconds); the
            # margin is for samples still queued on a loaded machine, not a speed requirement
            assert abs(ts[-1] - pylsl.local_clock()) < 60.0
            assert np.allclose(np.diff(ts), 1 / 256, atol=1e-4)
            assert inlet.wall_clock is False
        finally:
            inlet.close()
    assert sim.samples_pushed >= 256 and sim.error is None


def test_inlet_maps_wall_clock_stamps():
    """muselsl without --lsltime stamps with time.time(): the inlet maps them onto the LSL clock."""
    sid = _uid("MuseWall")
    with SimulatedMuse.start(np.random.default_rng(2), source_id=sid, wall_clock=True):
        inlet = EEGInlet.open(resolve_eeg(StreamQuery("EEG", source_id=sid), 5.0))
        try:
            ts = np.empty(0)
            deadline = time.monotonic() + 5
            while len(ts) == 0 and time.monotonic() < deadline:
                _, ts = inlet.pull(0.2)
            import pylsl

            assert inlet.wall_clock is True
            assert abs(ts[-1] - pylsl.local_clock()) < 0.5
            assert any("wall-clock" in w for w in inlet.warnings)
        finally:
            inlet.close()


def test_inlet_without_labels_assumes_muse_order():
    import pylsl

    sid = _uid("NoLabels")
    info = pylsl.StreamInfo("Other", "EEG", 6, 128, pylsl.cf_float32, sid)
    outlet = pylsl.StreamOutlet(info)
    try:
        inlet = EEGInlet.open(resolve_eeg(StreamQuery("EEG", source_id=sid), 5.0))
        assert inlet.scalp_index == (0, 1, 2, 3) and inlet.fs == 128
        assert "none of the muse channel labels" in inlet.warnings[0]
        inlet.close()
    finally:
        del outlet


def test_replay_publishes_raw_samples_in_order(raw_root):
    session = raw_root / "user_23" / "session_1"
    data, boundaries = load_raw_session(session)
    assert boundaries[0] == ("intro", 0) and boundaries[1][0] == "robot_1" and boundaries[2][0] == "user_1"
    sid = _uid("Replay")
    with ReplayMuse.start(session, source_id=sid):
        inlet = EEGInlet.open(resolve_eeg(StreamQuery("EEG", source_id=sid), 5.0))
        try:
            assert inlet.fs == 220.0 and inlet.scalp_labels == ("TP9", "AF7", "AF8", "TP10")
            got = []
            deadline = time.monotonic() + 6
            while sum(len(g) for g in got) < 400 and time.monotonic() < deadline:
                x, _ = inlet.pull(0.2)
                got.append(x)
            x = np.concatenate(got)
        finally:
            inlet.close()
    # the inlet joined a few chunks late: what it got is a contiguous run of the file, in order
    first = np.flatnonzero(np.all(np.isclose(data.astype(np.float32), x[0].astype(np.float32)), axis=1))
    assert len(first) >= 1
    start = int(first[0])
    assert start < 220  # joined within the first second
    assert np.array_equal(x.astype(np.float32), data[start : start + len(x)].astype(np.float32))


def test_raw_eeg_errors_report_file_and_line(tmp_path):
    good = "eeg 1 2 3 4\na 0.1 0.2 0.3 0.4\neeg 5 6 7 8\n"
    (tmp_path / "robot_1").write_text(good)
    assert read_recording(tmp_path / "robot_1", prefixes=("eeg",))["eeg"].tolist() == [[1, 2, 3, 4], [5, 6, 7, 8]]
    (tmp_path / "user_1").write_text(good + "eeg 9 10\n")
    with pytest.raises(DataError, match=r"user_1 line 4: expected 4 values after 'eeg', got 2"):
        load_raw_session(tmp_path)
    (tmp_path / "user_1").write_text("eeg 1 x 3 4\n")
    with pytest.raises(DataError, match=r"user_1 line 1: 'eeg' value 'x' is not a number"):
        read_recording(tmp_path / "user_1", prefixes=("eeg",))
    with pytest.raises(DataError, match="robot_1: not a folder"):
        load_raw_session(tmp_path / "robot_1")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DataError, match="no raw recordings"):
        load_raw_session(empty)


def test_cli_simulate_muse_runs_until_sigint():
    sid = _uid("CliMuse")
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "simulate-muse", "--seed", "5", "--source-id", sid,
                             "--engagement", "0.9"], stderr=subprocess.PIPE, text=True, env=env)
    try:
        ready = proc.stderr.readline()
        assert "ready" in ready and sid in ready
        info = resolve_eeg(StreamQuery("EEG", source_id=sid), 5.0)
        assert info is not None and info.channel_count() == 5
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 130  # an interrupt, as the README promises for every command
        assert "stopped after" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_cli_simulate_muse_rejects_bad_engagement():
    from nao_trainer.cli import main

    assert main(["simulate-muse", "--engagement", "1.5"]) == 2


def test_resolve_prefers_muse_and_honours_its_timeout():
    import pylsl

    kind = _uid("EEGtype")
    other = pylsl.StreamOutlet(pylsl.StreamInfo("Other", kind, 4, 256, pylsl.cf_float32, _uid("o")))
    muse = pylsl.StreamOutlet(pylsl.StreamInfo("Muse", kind, 4, 256, pylsl.cf_float32, _uid("m")))
    try:
        info = resolve_eeg(StreamQuery(kind), 5.0)
        assert info is not None and info.name() == "Muse"
        assert resolve_eeg(StreamQuery(kind, name="Other"), 5.0).name() == "Other"
    finally:
        del other, muse


def test_resolve_gives_up_when_its_own_clock_passes_the_timeout(monkeypatch):
    """The timeout is honoured on the clock resolve_eeg reads (injected here), never on a wall-clock bound:
    with nothing matching, it polls until the clock passes the deadline and then returns None."""
    import nao_trainer.eeg.inlet as inlet_mod

    now = [1000.0]
    polls = []

    def clock() -> float:
        return now[0]

    def sleep(s: float) -> None:  # each poll advances the injected clock
        polls.append(s)
        now[0] += 0.1

    monkeypatch.setattr(inlet_mod.time, "monotonic", clock)
    monkeypatch.setattr(inlet_mod.time, "sleep", sleep)
    assert resolve_eeg(StreamQuery(_uid("EEGtype"), name="Absent"), 0.5) is None
    assert 4 <= len(polls) <= 6  # stopped once 0.5 s had passed on its clock, not later, not at once
    polls.clear()
    assert resolve_eeg(StreamQuery(_uid("EEGtype"), name="Absent"), 2.0) is None
    assert 19 <= len(polls) <= 21
