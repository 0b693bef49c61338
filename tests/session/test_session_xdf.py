"""session.xdf of whole sessions (`nao-trainer run` as users start it): streams, samples, every turn's markers,
and a killed session's file."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.eeg import xdf

pyxdf = pytest.importorskip("pyxdf")
pytestmark = pytest.mark.skipif(not xdf.available(), reason="labrecorder not installed")

STUDY = """\
study: {{name: xdf}}
robot: {{url: mock}}
session: {{turns: {turns}, practice: false}}
timing: {{speed: {speed}}}
answers: {{input: simulated}}
policy: {{kind: schedule, schedule: [L1, L2, RF1, L3]}}
eeg: {{mode: simulated, processing: {{window_s: 0.25, hop_s: 0.05}}}}
"""
TURN_MARKERS = ("start", "listening_start", "listening_end", "answer_start", "answer_end", "end")


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _start(tmp_path: Path, turns: int, speed: float) -> tuple[subprocess.Popen, Path, str]:
    cfg = tmp_path / "study.yaml"
    cfg.write_text(STUDY.format(turns=turns, speed=speed))
    pseudonym = f"X{os.getpid()}{uuid.uuid4().hex[:6]}"
    out = tmp_path / "sessions"
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--config", str(cfg), "--pseudonym", pseudonym,
                             "--seed", "3", "--out", str(out), "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, QI_LOG_LEVEL="silent"))
    return proc, out, pseudonym


def _load(path: Path) -> dict:
    """The streams as recorded: the pushed LSL stamps (no clock sync, no dejitter), for exact comparisons."""
    streams, _ = pyxdf.load_xdf(str(path), synchronize_clocks=False, dejitter_timestamps=False)
    return {s["info"]["name"][0]: s for s in streams}


def test_session_xdf_holds_the_eeg_and_every_turns_markers(tmp_path):
    proc, out, pseudonym = _start(tmp_path, turns=5, speed=40)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert "Opened the stream" not in stdout + stderr and "footer" not in stdout + stderr  # engine lines: log only
    (folder,) = [p for p in out.iterdir() if (p / "session.json").exists()]
    assert "Wrote footer for stream Muse" in (folder / "eeg" / "xdf.log").read_text()
    s = _load(folder / "session.xdf")
    assert set(s) == {"Muse", "Markers"}
    eeg, mk = s["Muse"], s["Markers"]
    stream = json.loads((folder / "eeg" / "stream.json").read_text())
    assert eeg["info"]["source_id"][0] == stream["source_id"]
    assert mk["info"]["source_id"][0] == f"nao-trainer-markers-{pseudonym}-{folder.name}"  # this session's alone
    assert int(eeg["info"]["channel_count"][0]) == 5 == eeg["time_series"].shape[1]
    assert int(mk["info"]["channel_count"][0]) == 1
    assert int(eeg["footer"]["info"]["sample_count"][0]) == len(eeg["time_stamps"])
    assert len(eeg["clock_times"]) >= 1 and len(mk["clock_times"]) >= 1  # clock offsets recorded

    # the EEG: the samples the monitor saved in raw.csv, same values, same LSL times, none missing in between
    raw = np.loadtxt(folder / "eeg" / "raw.csv", delimiter=",", skiprows=1)
    at = {tuple(v): i for i, v in enumerate(eeg["time_series"][:, :4].astype(float))}
    idx = np.array([at.get(tuple(v), -1) for v in raw[:, 1:]])
    found = np.flatnonzero(idx >= 0)
    first, last = found[0], found[-1]
    assert last - first > 256 * 2 and (idx[first:last + 1] >= 0).all()  # every raw sample of the span is in the file
    assert (np.diff(idx[first:last + 1]) == 1).all()  # ... in order, and the file has none raw.csv lacks
    # raw.csv stamps are the source's stamps plus the inlet's clock correction (stream.json)
    shift = raw[first:last + 1, 0] - eeg["time_stamps"][idx[first:last + 1]]
    np.testing.assert_allclose(shift, stream["time_offset_s"], atol=1e-6)

    # the markers: every turn's, at the times the monitor stamped (events.csv) and the session logged
    names = [v[0] for v in mk["time_series"]]
    times = dict(zip(names, mk["time_stamps"]))
    turns = _rows(folder / "turns.csv")
    assert len(turns) == 5 and "session_start" in names and "session_end" in names
    for row in turns:
        for m in TURN_MARKERS:
            assert f"turn_{row['turn']}_{m}" in names, (row["turn"], m, names)
    stamped = {r["event"]: float(r["lsl_time"]) for r in _rows(folder / "eeg" / "events.csv")}
    for name, t in times.items():
        assert abs(t - stamped[name]) < 2e-6, name  # the stamp pushed (events.csv keeps 6 decimals)
    with open(folder / "events.jsonl") as fh:
        events = [json.loads(line) for line in fh]
    for ev in events:  # events.jsonl's monotonic clock is the LSL clock on Linux
        if ev["event"] in ("turn_start", "turn_end"):
            assert abs(times[f"turn_{ev['turn']}_{ev['event'][5:]}"] - ev["mono"]) < 0.05, ev
    assert sorted(mk["time_stamps"]) == list(mk["time_stamps"])
    # turns.csv's start times (wall clock, ms) are as far apart as the turns' start markers (LSL clock)
    from datetime import datetime

    wall = np.array([datetime.fromisoformat(r["start_time"]).timestamp() for r in turns])
    lsl = np.array([times[f"turn_{r['turn']}_start"] for r in turns])
    np.testing.assert_allclose(np.diff(wall), np.diff(lsl), atol=0.05)


def _recorder_alive(folder: Path) -> bool:
    """A recorder process writing into ``folder`` (its --out names the session folder)."""
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().split(b"\0")
        except OSError:
            continue
        if b"nao_trainer.eeg.xdf" in args and any(str(folder).encode() in a for a in args):
            return True
    return False


@pytest.mark.slow
def test_a_killed_session_leaves_a_complete_readable_xdf(tmp_path):
    proc, out, _ = _start(tmp_path, turns=40, speed=20)
    deadline = time.monotonic() + 60
    folder = None
    try:
        while time.monotonic() < deadline:
            folders = [p for p in out.iterdir() if (p / "session.json").exists()] if out.exists() else []
            if folders and (folders[0] / "turns.csv").exists() and len(_rows(folders[0] / "turns.csv")) >= 3:
                folder = folders[0]
                break
            time.sleep(0.1)
        assert folder is not None, "the session did not play 3 turns"
        killed_at = time.monotonic()  # the LSL clock on Linux
        os.kill(proc.pid, signal.SIGKILL)  # no clean-up at all in the session
    finally:
        proc.kill()
        proc.communicate(timeout=30)
    log = folder / "eeg" / "xdf.log"
    # The recorder notices, records its flush second and writes the footers. With the session's streams gone
    # liblsl's time-correction queries may hang the engine's stop: then the recorder's alarm ends it (no
    # footers; pyxdf reads the file all the same). Either way it must not outlive its session: wait for it to go.
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and _recorder_alive(folder):
        time.sleep(0.2)
    assert not _recorder_alive(folder), "the XDF recorder outlived its session"
    stopped = "xdf: stopped" in log.read_text()
    assert json.loads((folder / "session.json").read_text())["status"] == "running"  # killed: never closed
    s = _load(folder / "session.xdf")
    # Stopped in time, the recorder wrote the footers (read from the file: the engine's per-stream threads
    # write their "Wrote footer" log lines unlocked, and two of them once came out interleaved).
    assert not stopped or int(s["Markers"]["footer"]["info"]["sample_count"][0]) == len(s["Markers"]["time_series"])
    names = [v[0] for v in s["Markers"]["time_series"]]
    # Markers still in flight when the session's process died die with its outlet (LSL sends them
    # asynchronously): every marker the monitor stamped up to half a second before the kill is in the file,
    # in order, at its stamp, and so are the markers of every turn completed by then.
    stamped = [(r["event"], float(r["lsl_time"])) for r in _rows(folder / "eeg" / "events.csv")[:-1]
               if not r["event"].startswith(("eeg_stream_rejected", "eeg_error", "xdf_"))]
    settled = [(e, t) for e, t in stamped if t < killed_at - 0.5 and not e.startswith("eeg_stream_found")]
    assert len(settled) > 10 and [e for e, _ in settled] == names[: len(settled)]
    np.testing.assert_allclose(s["Markers"]["time_stamps"][: len(settled)], [t for _, t in settled], atol=2e-6)
    done = [int(e.split("_")[1]) for e, _ in settled if e.startswith("turn_") and e.endswith("_end")
            and not e.endswith(("listening_end", "answer_end"))]
    assert len(done) >= 2
    for n in done:
        assert f"turn_{n}_start" in names and f"turn_{n}_end" in names
    assert len(s["Muse"]["time_stamps"]) > 256
