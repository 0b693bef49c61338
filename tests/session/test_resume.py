"""`nao-trainer run --resume SESSION_DIR`: a session killed with SIGKILL continues as if never interrupted."""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.errors import DataError, Interrupted
from nao_trainer.session.config import DEFAULT_CONFIG, load_config
from nao_trainer.session.record import CHECKPOINT, read_events, read_turns
from nao_trainer.session.resume import prepare_resume
from nao_trainer.session.wiring import RunOptions, run_session

ROOT = Path(__file__).resolve().parents[2]
TIMING = {"start_time", "reaction_time", "completion_time"}  # wall-clock columns differ between runs


def study(tmp_path: Path) -> Path:
    text = (ROOT / "config" / "studies" / "demo.yaml").read_text()
    # x10, not the demo's x25: two sessions side by side (and another test run beside) must give their presses
    # the same outcome, so the answer windows keep room for a busy machine
    text = text.replace("mode: simulated", 'mode: "off"').replace("speed: 25", "speed: 10")
    text = text.replace('state_path: "{session}"', "state_path: null")  # per participant (the default)
    # Both runs must see the same presses: without a debounce no press of the simulated hand can be
    # merged with the one before when the machine is busy (the comparison is about the random streams).
    text = text.replace("answers:\n  input: simulated", "answers:\n  input: simulated\n  debounce_s: 0.0")
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return path


def run(*args: str, **kw) -> subprocess.Popen:
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, stdin=subprocess.DEVNULL, **kw)


def comparable(rows):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


@pytest.mark.slow
def test_a_killed_session_resumes_and_plays_the_same_turns_as_an_uninterrupted_one(tmp_path):
    cfg = study(tmp_path)
    assert "debounce_s: 0.0" in cfg.read_text()
    flags = ["--config", str(cfg), "--turns", "8", "--seed", "77", "--pseudonym", "R", "--quiet"]
    whole = run(*flags, "--out", str(tmp_path / "a"))
    killed = run(*flags, "--out", str(tmp_path / "b"))
    try:
        deadline = time.monotonic() + 90
        folder = None
        while time.monotonic() < deadline:  # killed in the assessment (6 turns), resumed into the policy's turns
            folders = list((tmp_path / "b").glob("R_*"))
            if folders and (folders[0] / "turns.csv").exists() and len(read_turns(folders[0])) >= 3:
                folder = folders[0]
                break
            time.sleep(0.02)
        assert folder is not None, "the session did not play 3 turns"
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
    finally:
        killed.kill()
    assert whole.wait(120) == 0, whole.stderr.read()
    before = (folder / "turns.csv").read_bytes()
    n_before = len(read_turns(folder))
    assert json.loads((folder / "session.json").read_text())["status"] == "running"  # killed: never closed
    shutil.copytree(folder, tmp_path / "copy")

    resumed = run("--resume", str(folder))
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    assert "resuming" in err and "status: completed" in out

    expected = read_turns(next((tmp_path / "a").glob("R_*")))
    got = read_turns(folder)
    assert (folder / "turns.csv").read_bytes().startswith(before)  # appended, never rewritten
    assert len(got) == 8 and n_before < 8
    assert comparable(got) == comparable(expected)
    info = json.loads((folder / "session.json").read_text())
    assert info["status"] == "completed" and len(info["resumptions"]) == 1
    assert info["resumptions"][0]["after_turn"] in (n_before, n_before + 1)  # +1: killed between checkpoint and row
    resumed_ev = [e for e in read_events(folder) if e["event"] == "resumed"]
    assert len(resumed_ev) == 1 and resumed_ev[0]["after_turn"] >= n_before

    # refused: a complete folder, another version, a changed configuration; flags with --resume
    res = run("--resume", str(folder))
    _, err = res.communicate(timeout=60)
    assert res.returncode == 2 and "the session is complete" in err and "Traceback" not in err
    with pytest.raises(DataError, match="another|written by nao-trainer 0.0.1"):
        other = tmp_path / "other"
        shutil.copytree(tmp_path / "copy", other)
        info = json.loads((other / "session.json").read_text())
        info["nao_trainer"] = "0.0.1"
        (other / "session.json").write_text(json.dumps(info))
        prepare_resume(other)
    prepare_resume(tmp_path / "copy")  # still resumable before the study changes
    cfg.write_text(cfg.read_text().replace("turns: 25", "turns: 24"))
    with pytest.raises(DataError, match="configuration changed since the session started"):
        prepare_resume(tmp_path / "copy")
    res = run("--resume", str(tmp_path / "copy"), "--turns", "3")
    _, err = res.communicate(timeout=60)
    assert res.returncode == 2 and "drop session.turns" in err


def test_a_folder_without_a_completed_turn_or_session_json_is_refused(tmp_path):
    with pytest.raises(DataError, match="not a session folder"):
        prepare_resume(tmp_path)
    (tmp_path / "session.json").write_text(json.dumps({"status": "interrupted", "nao_trainer": __import__("nao_trainer").__version__}))
    with pytest.raises(DataError, match="no completed turn to resume from"):
        prepare_resume(tmp_path)


# -- in-process: an interrupted session, then a torn row or a tampered checkpoint ---------------------------------


class InterruptAfter:
    """An observer that stops the session like SIGTERM once ``n`` turns are recorded (status "interrupted")."""

    def __init__(self, n: int) -> None:
        self.n, self.rows = n, 0

    def notify(self, kind: str, data: dict) -> None:
        if kind == "row" and data.get("success") is not None:
            self.rows += 1
            if self.rows == self.n:
                raise Interrupted("SIGTERM")


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> Path:
    """A usp:2 session of 6 turns interrupted after turn 3 (learning state per participant)."""
    out = tmp_path_factory.mktemp("interrupted")
    cfg = load_config(DEFAULT_CONFIG, {"session.turns": 6, "timing.speed": 50.0, "session.output": str(out),
                                       "eeg.mode": "off", "session.practice": False, "participant.pseudonym": "T",
                                       "policy.kind": "usp:2", "session.seed": 8})
    result = run_session(cfg, RunOptions(quiet=True, observer=InterruptAfter(3)))
    assert result.status == "interrupted" and len(read_turns(result.path)) == 3
    return result.path


def copy_of(folder: Path, tmp_path: Path) -> Path:
    target = tmp_path / "session" / folder.name
    shutil.copytree(folder, target)
    shutil.copytree(folder.parent / "participants", tmp_path / "session" / "participants")
    return target


@pytest.mark.parametrize("cut", list(np.random.default_rng(17).integers(30, 91, size=3)))
def test_resume_after_a_torn_last_row_drops_the_tail_before_appending(interrupted, tmp_path, cut):
    folder = copy_of(interrupted, tmp_path)
    data = (folder / "turns.csv").read_bytes()
    (folder / "turns.csv").write_bytes(data[:-int(cut)])  # a kill in the middle of the last row
    cfg, resumption = prepare_resume(folder)
    assert resumption.missing_row is not None and resumption.missing_row["turn"] == 3  # from the checkpoint
    result = run_session(cfg, RunOptions(quiet=True), resume=resumption)
    assert result.exit_code == 0
    rows = read_turns(folder)
    assert [r["turn"] for r in rows] == ["1", "2", "3", "4", "5", "6"]
    assert all(None not in r.values() and None not in r for r in rows)  # every row whole, none glued to another
    assert any(e["event"] == "torn_row_dropped" for e in read_events(folder))


#: Tampered checkpoint.json / session.json / turns.csv: each must be refused in one line (exit 2).
TAMPER_KEYS = ("completed", "total", "mdp_state", "last_success", "elapsed_s", "row", "rng", "policy")
BAD_VALUES = {
    "completed": [0, 20, 999, "3", None, 2.5, 5], "total": [1000000, -1000000, "x", None],
    "mdp_state": [999, -1, 108, "L1", None], "last_success": ["yes", None, 1], "elapsed_s": [-1, "x", None, float("nan")],
    "row": [None, [], {"turn": 99}, "row"], "rng": [None, [], {"session": "garbage", "policy": {}}, {}],
    "policy": [None, [], {}, {"q": "x"}, {"q": [[1]], "h": [], "h_counts": [], "visits": [], "live": {}, "guided": []}],
    "override": [99, "L1", -1], "learn": ["x", {"state": 1}],
}


def tamper(folder: Path, rng: np.random.Generator) -> str:
    cp_path, info_path = folder / CHECKPOINT, folder / "session.json"
    cp = json.loads(cp_path.read_text())
    kind = rng.choice(["drop", "value", "value", "value", "file"])
    if kind == "drop":
        key = str(rng.choice(TAMPER_KEYS))
        del cp[key]
        cp_path.write_text(json.dumps(cp))
        return f"no {key}"
    if kind == "value":
        key = str(rng.choice(sorted(BAD_VALUES)))
        value = BAD_VALUES[key][int(rng.integers(len(BAD_VALUES[key])))]
        cp[key] = value
        cp_path.write_text(json.dumps(cp))
        return f"{key}={value!r}"
    what = str(rng.choice(["no turns.csv", "checkpoint []", "seed x", "no config", "garbage row"]))
    if what == "no turns.csv":
        (folder / "turns.csv").unlink()
    elif what == "checkpoint []":
        cp_path.write_text("[]")
    elif what == "garbage row":
        lines = (folder / "turns.csv").read_text().splitlines(keepends=True)
        lines.insert(2, "x,y,z,1,2\r\n")
        (folder / "turns.csv").write_text("".join(lines))
    else:
        info = json.loads(info_path.read_text())
        if what == "seed x":
            info["seed"] = "x"
        else:
            info["config"] = []
        info_path.write_text(json.dumps(info, indent=2))
    return what


def test_a_tampered_checkpoint_is_refused_in_one_line_and_the_session_keeps_its_status(interrupted, tmp_path):
    """A seeded fuzz of checkpoints (like the config fuzz): exit 2, one line, no traceback, session.json untouched."""
    from nao_trainer.cli import main

    rng = np.random.default_rng(2026)
    for i in range(30):
        folder = copy_of(interrupted, tmp_path / str(i))
        what = tamper(folder, rng)
        before = (folder / "session.json").read_bytes()
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(["run", "--resume", str(folder), "--quiet"])
        except BaseException as exc:  # noqa: BLE001 - what the fuzz looks for
            pytest.fail(f"{what}: {type(exc).__name__}: {exc}")
        lines = err.getvalue().strip().splitlines()  # "resuming FOLDER after turn 3 of 6", then the refusal
        errors = [ln for ln in lines if "error:" in ln]
        assert code == 2 and len(errors) == 1 and lines[-1] == errors[0], (what, code, lines)
        assert "Traceback" not in err.getvalue() and lines[-1].startswith("nao-trainer run: error: "), (what, lines)
        assert (folder / "session.json").read_bytes() == before, what  # not marked "error"
        assert not (folder / "turns.csv").exists() or "resumed" not in (folder / "events.jsonl").read_text()


# -- issue 30, finding 7: a resumed folder is not trusted further than its files are checked -------------------


def resume_refusal(folder: Path) -> str:
    """Run ``run --resume`` in this process; assert a one-line refusal (exit 2, no traceback) and return it."""
    from nao_trainer.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["run", "--resume", str(folder), "--quiet"])
    lines = err.getvalue().strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("nao-trainer run: error: "), (code, lines)
    return lines[0]


@pytest.mark.parametrize("name", ["turns.csv", "events.jsonl"])
def test_a_symlinked_file_in_the_session_folder_is_refused_and_its_target_untouched(interrupted, tmp_path, name):
    """The link was followed and 15 rows appended to its target, exit 0."""
    folder = copy_of(interrupted, tmp_path)
    target = tmp_path / f"elsewhere-{name}"
    shutil.move(folder / name, target)
    (folder / name).symlink_to(target)
    before = target.read_bytes()
    msg = resume_refusal(folder)
    assert f"{folder / name}: a symbolic link in the session folder" in msg
    assert target.read_bytes() == before


def test_a_fifo_in_the_session_folder_is_refused_before_anything_is_read(interrupted, tmp_path):
    folder = copy_of(interrupted, tmp_path)
    (folder / "events.jsonl").unlink()
    os.mkfifo(folder / "events.jsonl")
    assert f"{folder / 'events.jsonl'}: not a regular file" in resume_refusal(folder)


def test_reopen_refuses_a_link_planted_after_the_checks(interrupted, tmp_path):
    """The files are opened with O_NOFOLLOW too (a link put in place between the checks and the appends)."""
    from nao_trainer.session.record import SessionRecorder

    folder = copy_of(interrupted, tmp_path)
    target = tmp_path / "elsewhere.csv"
    shutil.move(folder / "turns.csv", target)
    (folder / "turns.csv").symlink_to(target)
    with pytest.raises(OSError):
        SessionRecorder(folder.parent, "T").reopen(folder, {"after_turn": 3})
    assert not os.path.islink(target)


def edit_rows(folder: Path, edit) -> None:
    lines = (folder / "turns.csv").read_bytes().decode().splitlines(keepends=True)
    (folder / "turns.csv").write_bytes("".join(edit(lines)).encode())


def _score_edited(lines: list[str]) -> list[str]:
    """Turn 1's score raised by 1 (signed score left): a number the session never writes."""
    import csv as _csv

    rows = list(_csv.DictReader(io.StringIO("".join(lines), newline="")))
    rows[0]["score"] = str(int(rows[0]["score"]) + 1)
    out = io.StringIO(newline="")
    writer = _csv.DictWriter(out, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue().splitlines(keepends=True)


def _both_scores_edited(lines: list[str]) -> list[str]:
    """Turn 2 turned from its outcome into the other one, consistently (success, response, both scores):
    every row is one a session could write, but the table no longer sums to the checkpoint's total."""
    import csv as _csv

    rows = list(_csv.DictReader(io.StringIO("".join(lines), newline="")))
    r, level = rows[1], int(rows[1]["level"])
    ok = r["success"] != "True"
    r.update(success=str(ok), response=r["sequence"] if ok else "", score=str(level if ok else -1),
             signed_score=str(level if ok else -level))
    out = io.StringIO(newline="")
    writer = _csv.DictWriter(out, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue().splitlines(keepends=True)


@pytest.mark.parametrize("edit, words", [
    (lambda lines: lines + [lines[-1]], "line 5: turn 3 is recorded twice (first on line 4)"),
    (lambda lines: lines[:2] + [lines[2].replace("2,", "3,", 1)] + lines[3:], "line 3: turn 3 where turn 2 belongs"),
    (lambda lines: lines[:2] + lines[3:], "line 3: turn 3 where turn 2 belongs"),
    (_score_edited, "line 2 (turn 1): score"),
    (_both_scores_edited, "the completed rows score"),
], ids=["last-row-twice", "renumbered", "row-removed", "score-edited", "outcome-flipped"])
def test_the_whole_turn_table_is_checked_against_the_checkpoint(interrupted, tmp_path, edit, words):
    """Only the last turn number was compared: a duplicated last row gave 21 turns of 20, an edited earlier
    score passed. Each is one line naming turns.csv and the row."""
    folder = copy_of(interrupted, tmp_path)
    edit_rows(folder, edit)
    msg = resume_refusal(folder)
    assert f"{folder}/turns.csv: " in msg and words in msg, msg


def test_the_last_row_must_be_the_checkpoints(interrupted, tmp_path):
    import csv as _csv

    folder = copy_of(interrupted, tmp_path)

    def edit(lines: list[str]) -> list[str]:
        rows = list(_csv.DictReader(io.StringIO("".join(lines), newline="")))
        rows[-1]["start_time"] = "2000-01-01T00:00:00.000+00:00"
        out = io.StringIO(newline="")
        writer = _csv.DictWriter(out, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        return out.getvalue().splitlines(keepends=True)

    edit_rows(folder, edit)
    msg = resume_refusal(folder)
    assert "line 4 (turn 3): start_time is '2000-01-01T00:00:00.000+00:00', the checkpoint recorded" in msg, msg


def test_a_torn_last_event_is_cut_before_events_are_appended(interrupted, tmp_path):
    """events.jsonl cut mid-line (a kill, or a full disk at its limit) got the resumed session's first event glued
    onto its half line: a line no JSON reader can read."""
    folder = copy_of(interrupted, tmp_path)
    data = (folder / "events.jsonl").read_bytes()
    (folder / "events.jsonl").write_bytes(data[:-25])
    cfg, resumption = prepare_resume(folder)
    result = run_session(cfg, RunOptions(quiet=True), resume=resumption)
    assert result.exit_code == 0
    events = read_events(folder)  # every line whole JSON
    assert any(e["event"] == "torn_event_dropped" for e in events)
