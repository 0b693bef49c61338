"""XDF recording with LabRecorder's engine over real LSL streams (machine scope, streams pinned by source_id)."""
from __future__ import annotations

import os
import signal
import time
import uuid

import numpy as np
import pytest

from nao_trainer.eeg import xdf
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.markers import MarkerOutlet
from nao_trainer.eeg.simulated_muse import SimulatedMuse

configure_lsl("machine")
pyxdf = pytest.importorskip("pyxdf")
pytestmark = pytest.mark.skipif(not xdf.available(), reason="labrecorder not installed")


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _streams(path):
    streams, _header = pyxdf.load_xdf(str(path))
    return {s["info"]["name"][0]: s for s in streams}


@pytest.fixture
def outlets():
    eeg = SimulatedMuse.start(np.random.default_rng(0), source_id=_uid("xdf-eeg"))
    markers = MarkerOutlet(_uid("xdf-markers"))
    yield eeg, markers
    markers.close()
    eeg.stop()


def test_recording_holds_every_marker_and_the_eeg_with_lsl_times(tmp_path, outlets, capfd):
    eeg, markers = outlets
    rec = xdf.XdfRecorder.start(tmp_path / "session.xdf", [eeg.source_id, markers.source_id],
                                log_path=tmp_path / "xdf.log", ready=markers.has_consumers, timeout_s=60)
    assert rec.ready
    flowing_from = _eeg_flowing_to_the_recorder(eeg)  # else, on a loaded machine, the inlet may connect late
    pushed = []
    for k in range(6):
        pushed.append((f"turn_{k}_start", markers.push("turn_start", k)))
        time.sleep(0.1)
    n_before = eeg.samples_pushed
    assert rec.stop() == 0
    streams = _streams(tmp_path / "session.xdf")
    assert set(streams) == {"Muse", "Markers"}
    m, e = streams["Markers"], streams["Muse"]
    assert [v[0] for v in m["time_series"]] == [name for name, _ in pushed]  # none lost, the first included
    np.testing.assert_allclose(m["time_stamps"], [t for _, t in pushed], atol=2e-3)  # LSL clock, synchronised
    assert int(e["info"]["channel_count"][0]) == 5 and e["time_series"].shape[1] == 5
    assert int(m["info"]["channel_count"][0]) == 1
    assert e["info"]["source_id"][0] == eeg.source_id and m["info"]["source_id"][0] == markers.source_id
    footer = int(e["footer"]["info"]["sample_count"][0])
    # every sample pushed once the recorder's inlet was flowing is in the file (those before may not be:
    # the outlet started before the recorder, how long before depends on the machine's load)
    assert footer == len(e["time_stamps"]) and n_before - flowing_from <= footer <= eeg.samples_pushed
    assert np.all(np.diff(e["time_stamps"]) > 0)
    assert e["time_stamps"][0] <= pushed[0][1] and e["time_stamps"][-1] >= pushed[-1][1]
    assert len(e["clock_times"]) > 0  # clock offsets were measured and stored
    out, err = capfd.readouterr()
    assert "Opened the stream" not in out + err and "footer" not in out + err  # the engine's lines: log only
    assert "Wrote footer" in (tmp_path / "xdf.log").read_text()


def test_a_killed_recorder_leaves_a_file_readable_up_to_what_was_written(tmp_path, outlets):
    eeg, markers = outlets
    rec = xdf.XdfRecorder.start(tmp_path / "s.xdf", [eeg.source_id, markers.source_id],
                                log_path=tmp_path / "xdf.log", ready=markers.has_consumers, timeout_s=60)
    assert rec.ready
    early = [markers.push("turn_start", k) for k in range(3)]
    deadline = time.monotonic() + 60  # a hang limit: the engine writes in chunks, later on a loaded machine
    written = 0
    while time.monotonic() < deadline and written <= 256:  # until over a second of EEG is in the file
        time.sleep(0.2)
        written = _eeg_samples_in(tmp_path / "s.xdf")
    assert written > 256, "the recorder wrote no second of EEG within 60 s"
    markers.push("late_marker")
    os.kill(rec.process.pid, signal.SIGKILL)
    rec.process.wait(5)
    streams = _streams(tmp_path / "s.xdf")  # no footers: still readable
    names = [v[0] for v in streams["Markers"]["time_series"]]
    assert names[:3] == ["turn_0_start", "turn_1_start", "turn_2_start"]
    np.testing.assert_allclose(streams["Markers"]["time_stamps"][:3], early, atol=2e-3)
    assert len(streams["Muse"]["time_stamps"]) >= written  # what was written before the kill is all there


def _eeg_flowing_to_the_recorder(eeg) -> int:
    """Wait (a hang limit, not a time claim) until the EEG outlet has the recorder as consumer and has pushed
    two chunks since; returns the samples pushed by then: every sample from then on reaches the file."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not eeg.has_consumers():
        time.sleep(0.02)
    assert eeg.has_consumers(), "the recorder did not connect to the EEG stream within 60 s"
    start = eeg.samples_pushed
    while time.monotonic() < deadline and eeg.samples_pushed < start + 2 * eeg.chunk:
        time.sleep(0.02)
    return eeg.samples_pushed


def _eeg_samples_in(path) -> int:
    """EEG samples pyxdf reads from a file still being written (0 while it cannot read it yet)."""
    try:
        return len(_streams(path).get("Muse", {}).get("time_stamps", []))
    except Exception:  # noqa: BLE001 - a chunk half written: not yet
        return 0


def test_no_stream_or_no_engine_is_one_line(tmp_path, monkeypatch):
    with pytest.raises(xdf.XdfUnavailable, match=r"no LSL stream with source_id nobody-\S+ within 0.5 s"):
        xdf.XdfRecorder.start(tmp_path / "x.xdf", [_uid("nobody")], timeout_s=10, resolve_s=0.5)
    monkeypatch.setattr(xdf, "available", lambda: False)
    with pytest.raises(xdf.XdfUnavailable, match=r"pip install 'nao-trainer\[xdf\]'"):
        xdf.XdfRecorder.start(tmp_path / "x.xdf", ["a"])


def _recorders_of(out: str) -> list[int]:
    """Process ids of recorder children writing ``out`` (read from /proc: no dependency on the parent's objects)."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmd = open(f"/proc/{entry}/cmdline", "rb").read().split(b"\0")
            except OSError:
                continue
            if b"nao_trainer.eeg.xdf" in cmd and out.encode() in cmd:
                pids.append(int(entry))
    return pids


def _gone(out: str, limit_s: float = 60.0) -> bool:
    """Wait (an event, with a generous limit) for every recorder of ``out`` to end."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if not _recorders_of(out):
            return True
        time.sleep(0.1)
    return False


def test_an_interrupted_start_up_never_leaves_the_recorder_behind(tmp_path):
    """SIGTERM (Interrupted) while start() waits for the recorder: the child is killed before the exception goes on."""
    from nao_trainer.errors import Interrupted

    out = tmp_path / "session.xdf"
    seen = []

    def ready() -> bool:
        raise Interrupted("SIGTERM")

    original = xdf.XdfRecorder._recording
    try:
        xdf.XdfRecorder._recording = lambda self: seen.append(self.process.pid) or True  # ask ready() at once
        with pytest.raises(Interrupted):
            xdf.XdfRecorder.start(out, [_uid("absent")], ready=ready, resolve_s=600.0)
    finally:
        xdf.XdfRecorder._recording = original
    assert seen and _gone(str(out))


@pytest.mark.skipif(not os.path.exists("/proc/self/cmdline"), reason="needs Linux /proc")
def test_the_recorder_dies_with_a_session_killed_during_eeg_start_up(tmp_path):
    """SIGKILL of the session while the recorder still looks for its streams (600 s): it ends with it."""
    import subprocess
    import sys

    out = tmp_path / "session.xdf"
    code = ("import sys; from nao_trainer.eeg import xdf; "
            f"xdf.XdfRecorder.start({str(out)!r}, ['absent-{uuid.uuid4().hex}'], timeout_s=600, resolve_s=600)")
    session = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not _recorders_of(str(out)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _recorders_of(str(out)), "the recorder did not start"
    finally:
        session.kill()
        session.wait(10)
    assert _gone(str(out)), "the recorder outlived its session"


STUCK_RECORDER = """
import signal, sys, time
from nao_trainer.eeg import xdf
guard = xdf.start_guard(int(sys.argv[1]), grace_s=0.5, poll_s=0.05)
# What the engine did to two orphans: stuck with the GIL held, so no Python handler ran; here SIGTERM
# (the parent-death signal, and what an operator would send) and SIGINT are simply blocked.
signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
print(guard, flush=True)
time.sleep(600)
"""

SESSION = """
import os, subprocess, sys, time
rec = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(os.getpid())], stdout=subprocess.PIPE, text=True)
print(rec.pid, rec.stdout.readline().strip(), flush=True)
time.sleep(600)
"""


def test_a_recorder_that_cannot_act_on_signals_is_still_ended_by_its_guard_once_the_session_is_gone():
    """Two recorders outlived killed sessions by 12 and 17 minutes, deaf to SIGTERM (the engine held the
    GIL). ``start_guard`` forks a process that SIGKILLs the recorder once its session has been gone for
    the grace period; while the session lives it does nothing, and it ends with the recorder."""
    import subprocess
    import sys

    session = subprocess.Popen([sys.executable, "-c", SESSION, STUCK_RECORDER], stdout=subprocess.PIPE, text=True)
    recorder, guard = None, None
    try:
        first, second = session.stdout.readline().split()
        recorder = int(first)
        assert second != "None", "no guard was started"
        guard = int(second)
        assert _pid_alive(recorder) and _pid_alive(guard)
        time.sleep(0.3)  # several of the guard's polls with the session alive: nothing happens
        assert _pid_alive(recorder), "the guard killed a recorder whose session was alive"
        session.kill()  # SIGKILL: the recorder is reparented and cannot stop itself
        session.wait(10)
        deadline = time.monotonic() + 60  # a hang limit; the grace is 0.5 s
        while time.monotonic() < deadline and (_pid_alive(recorder) or _pid_alive(guard)):
            time.sleep(0.05)
        assert not _pid_alive(recorder), "the stuck recorder outlived its session"
        assert not _pid_alive(guard), "the guard outlived the recorder"
    finally:
        session.kill()
        session.wait(10)
        for pid in (recorder, guard):  # a failed run leaves nothing behind
            if pid is not None and _pid_alive(pid):
                os.kill(pid, signal.SIGKILL)


def _pid_alive(pid: int) -> bool:
    """Running (not a zombie) by /proc."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False
