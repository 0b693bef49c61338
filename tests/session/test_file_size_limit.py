"""A full disk under `nao-trainer run`, made with a file size limit (``ulimit -f``: EFBIG, as ENOSPC would):
one line saying which file, why and how to fix, the right exit code, no traceback, every completed turn kept
(issue 30, finding 8 and the ENOSPC/EFBIG of run). The limit is set in the child only (RLIMIT_FSIZE in
preexec_fn); Python ignores SIGXFSZ, so a write past it fails with EFBIG instead of killing the process."""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

from nao_trainer.session.record import read_turns

HANG = 300  # a hang limit for the child (a sped-up session of a few turns takes seconds)


def run_limited(tmp_path: Path, limit: int, *args: str) -> subprocess.CompletedProcess:
    def limit_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = dict(os.environ, QI_LOG_LEVEL="silent", XDG_CACHE_HOME=str(tmp_path / "cache"))
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--no-keys", "--eeg", "off", "--quiet",
                           "--speed", "200", "--no-practice", "--seed", "3", "--out", str(tmp_path / "out"), *args],
                          capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL, timeout=HANG,
                          preexec_fn=limit_files)


def folder_of(tmp_path: Path) -> Path:
    (folder,) = (tmp_path / "out").glob("demo_*")
    return folder


def test_a_full_events_log_is_said_at_the_terminal_in_the_summary_and_by_the_exit_code(tmp_path):
    """events.jsonl stopped mid-line at 8192 bytes and the run said `status: completed (exit 0)`."""
    done = run_limited(tmp_path, 8192, "--turns", "12", "--policy", "schedule")
    folder = folder_of(tmp_path)
    assert done.returncode == 6, done.stderr
    warning = [ln for ln in done.stderr.splitlines() if "warning:" in ln]
    assert len(warning) == 1 and f"{folder / 'events.jsonl'}: cannot write (the file is larger than this system " \
        "allows)" in warning[0] and "ulimit -f" in warning[0], done.stderr
    status = [ln for ln in done.stdout.splitlines() if ln.startswith("status:")]
    assert status and status[0].startswith("status: completed (exit 6): ") and "events.jsonl" in status[0], done.stdout
    assert "Traceback" not in done.stderr
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and info["exit_code"] == 6 and "events.jsonl" in info["events_lost"]
    assert len(read_turns(folder)) == 12  # every turn kept


def test_a_checkpoint_too_large_to_write_ends_in_one_line_with_the_turn_kept(tmp_path):
    """The first checkpoint (60 KB with the demo's personalised policy) was a traceback (OSError: File too
    large) from files.write_text_atomic, and the answered turn was lost with it."""
    done = run_limited(tmp_path, 16384, "--turns", "3")
    folder = folder_of(tmp_path)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert lines[-1].startswith(f"nao-trainer run: error: {folder / 'checkpoint.json'}: cannot write (the file is "
                                "larger than this system allows); raise the file size limit (ulimit -f)"), lines
    assert [r["turn"] for r in read_turns(folder)] == ["1"]  # the answered turn is kept
    assert json.loads((folder / "session.json").read_text())["status"] == "error"


def test_no_room_for_session_json_at_the_start_is_one_line_and_promises_no_resumption(tmp_path):
    done = run_limited(tmp_path, 1024, "--turns", "3", "--policy", "schedule")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "session.json: cannot write (the file is larger than this system allows)" in lines[-1], lines
    assert "no turn was recorded" in lines[-1] and "--resume" not in lines[-1]


def test_eeg_files_past_the_limit_are_one_line_naming_the_file(tmp_path):
    """eeg/raw.csv past the limit was a traceback (OSError without a file name: raised by write())."""
    done = run_limited(tmp_path, 12288, "--turns", "3", "--policy", "schedule", "--eeg", "simulated")
    folder = folder_of(tmp_path)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert lines[-1].startswith("nao-trainer run: error: " + str(folder / "eeg")), lines
    assert "cannot write (the file is larger than this system allows); raise the file size limit" in lines[-1]


def xdf_chunk(tag: int, content: bytes) -> bytes:
    body = tag.to_bytes(2, "little") + content
    return bytes([4]) + len(body).to_bytes(4, "little") + body


def test_a_cut_xdf_file_is_found(tmp_path):
    """The XDF engine writes through a C++ stream that reports no error: a file cut by a full disk is found by
    walking its chunks (a whole file ends after its stream footers, tag 6)."""
    from nao_trainer.eeg.xdf import truncation

    whole = b"XDF:" + xdf_chunk(1, b"<info/>") + xdf_chunk(3, b"\x01" * 300) + xdf_chunk(6, b"<footer/>")
    path = tmp_path / "session.xdf"
    path.write_bytes(whole)
    assert truncation(path) is None
    for n, words in ((len(whole) - 3, "inside a chunk"), (len(whole) - len(xdf_chunk(6, b"<footer/>")),
                                                           "without its stream footers"), (2, "no XDF header")):
        path.write_bytes(whole[:n])
        assert words in truncation(path), n
