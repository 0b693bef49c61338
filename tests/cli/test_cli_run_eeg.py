"""`nao-trainer run` end to end with EEG (the demo with its simulated Muse, LSL streams), as users start it.

Split from test_cli_run.py so that the two halves run on different test workers (`--dist loadfile`).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session.record import read_events, read_turns


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


def only_folder(out: Path) -> Path:
    folders = list(out.iterdir())
    assert len(folders) == 1, folders
    return folders[0]


@pytest.mark.slow
def test_no_flags_plays_the_25_turn_demo(tmp_path):
    out = tmp_path / "sessions"
    res = cli("--out", str(out))  # exactly as `make demo` runs it (its speed: benchmarks/bench_session_demo.py)
    assert res.returncode == 0, res.stderr
    folder = only_folder(out)
    assert folder.name.startswith("demo_")
    rows = read_turns(folder)
    assert len(rows) == 25 and all(r["success"] in ("True", "False") for r in rows)
    progress = [ln for ln in res.stderr.splitlines() if ln.startswith("turn ")]
    assert len(progress) == 25 and " vs " in progress[0] and "total" in progress[0]
    assert "level  played  success rate" in res.stdout and f"session folder: {folder}" in res.stdout
    assert f"total score: {sum(int(r['score']) for r in rows)}" in res.stdout
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and info["robot"] == "stand-in (in-process)"
    # the demo shows the whole system: simulated Muse -> engagement per turn, a trained policy
    with_engagement = [r for r in rows if r["engagement"] not in ("", None)]
    assert len(with_engagement) >= 20, [r["notes"] for r in rows]
    assert all(0.0 <= float(r["engagement"]) <= 1.0 for r in with_engagement)
    assert " E 0." in res.stderr or " E 1." in res.stderr
    # ... and personalisation: assessment turns, then the level the strong simulated participant can do
    assert info["policy"] == "personalised" and info["user_model"] and (folder / "personalised.json").exists()
    assert [r["phase"] for r in rows[:7]] == ["assessment"] * 6 + ["personalised"]
    assert sum(r["level"] == "4" for r in rows[6:]) >= 10, [r["level"] for r in rows]
    assert "matched user model " in res.stdout
    assert (folder / "eeg" / "windows.csv").exists()


def test_simulated_eeg_fills_the_engagement_columns(tmp_path):
    # the demo study without session.xdf (recorded by the demo test above; its recorder's stop takes 5-20 s)
    study = tmp_path / "demo.yaml"
    study.write_text((PROJECT_ROOT / "config" / "studies" / "demo.yaml").read_text()
                     .replace("eeg:\n  mode: simulated\n", "eeg:\n  mode: simulated\n  xdf: false\n"))
    assert "  xdf: false\n" in study.read_text()
    out = tmp_path / "out"
    res = cli("--config", str(study), "--eeg", "simulated", "--turns", "2", "--no-practice", "--out", str(out),
              "--quiet", timeout=180)
    assert res.returncode == 0, res.stderr
    folder = only_folder(out)
    rows = read_turns(folder)
    assert len(rows) == 2
    for r in rows:
        assert r["engagement"] != "" or r["engagement_note"] != ""  # a value, or the reason there is none
    assert any(r["engagement_index"] != "" for r in rows)
    assert (folder / "eeg").is_dir()


def _study(tmp_path: Path, text: str) -> str:
    path = tmp_path / "study.yaml"
    path.write_text("study: {name: eeg-test}\n" + text)
    return str(path)


def test_the_chosen_eeg_stream_is_printed_recorded_and_can_be_pinned(tmp_path):
    """Two streams called Muse on the machine: --eeg-source-id takes the one asked for, and says which."""
    import uuid

    import numpy as np

    from nao_trainer.eeg.simulated_muse import SimulatedMuse

    wanted, decoy = (f"MusePin-{uuid.uuid4().hex[:8]}" for _ in range(2))
    streams = [SimulatedMuse.start(np.random.default_rng(i), source_id=sid) for i, sid in enumerate((decoy, wanted))]
    try:
        out = tmp_path / "out"
        res = cli("--eeg", "lsl", "--eeg-source-id", wanted, "--turns", "2", "--speed", "50", "--out", str(out),
                  "--config", _study(tmp_path, "eeg: {processing: {window_s: 0.5, hop_s: 0.1}}\n"))
    finally:
        for s in streams:
            s.stop()
    assert res.returncode == 0, res.stderr
    line = next(ln for ln in res.stderr.splitlines() if ln.startswith("EEG (lsl): "))
    assert f"stream 'Muse' (source_id '{wanted}', 256 Hz, channels TP9/AF7/AF8/TP10)" in line
    folder = only_folder(out)
    (event,) = [e for e in read_events(folder) if e["event"] == "session_start"]
    assert wanted in event["eeg"] and decoy not in event["eeg"]
    assert json.loads((folder / "eeg" / "stream.json").read_text())["source_id"] == wanted
    # issue 17: the record names the stream and says it was simulated (a simulated participant may use it)
    ident = json.loads((folder / "session.json").read_text())["eeg_stream"]
    assert ident["source_id"] == wanted and ident["simulated"] is True and ident["acquisition"] == "simulated"
    assert ident["name"] == "Muse" and ident["channel_count"] == 5 and ident["nominal_srate"] == 256.0


def test_a_person_answering_refuses_a_simulated_stream_with_exit_4(tmp_path):
    """Issue 17: `simulate-muse` was recorded as a tactile participant's EEG."""
    import uuid

    import numpy as np

    from nao_trainer.eeg.simulated_muse import SimulatedMuse

    sid = f"MuseSim-{uuid.uuid4().hex[:8]}"
    muse = SimulatedMuse.start(np.random.default_rng(0), source_id=sid)
    try:
        res = cli("--input", "tactile", "--eeg", "lsl", "--eeg-source-id", sid, "--turns", "1", "--speed", "50",
                  "--pseudonym", "P1", "--out", str(tmp_path / "out"), "--config", _study(tmp_path, "eeg: {required: false}\n"))
    finally:
        muse.stop()
    assert res.returncode == 4, res.stderr
    assert "Traceback" not in res.stderr and f"source_id '{sid}') is simulated" in res.stderr
    assert "--allow-simulated-eeg" in res.stderr


def test_a_missing_required_stream_stops_the_run_before_any_session_folder(tmp_path):
    out = tmp_path / "out"
    study = _study(tmp_path, "eeg: {mode: lsl, required: true, processing: {resolve_timeout_s: 1}}\n")
    res = cli("--config", study, "--eeg-source-id", "MuseNotHere-0", "--turns", "1", "--speed", "50", "--out", str(out))
    assert res.returncode == 4, res.stderr
    assert "no EEG stream" in res.stderr and "source_id 'MuseNotHere-0'" in res.stderr and "Traceback" not in res.stderr
    assert not out.exists() or not list(out.iterdir())  # refused before a session folder was made


def test_summary_says_why_there_is_no_engagement_when_eeg_was_on(tmp_path):
    study = _study(tmp_path, "eeg: {mode: lsl, required: false, processing: {resolve_timeout_s: 0.5}}\n")
    res = cli("--config", study, "--eeg-source-id", "MuseNotHere-1", "--turns", "1", "--speed", "50",
              "--out", str(tmp_path / "out"), "--no-practice")
    assert res.returncode == 0, res.stderr
    summary = next(ln for ln in res.stdout.splitlines() if "mean engagement" in ln)
    assert "n/a (EEG on, no value in any turn: " in summary and "EEG off" not in summary
