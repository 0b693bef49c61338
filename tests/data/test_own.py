"""Sessions written by `run` as data: offline engagement == live, import, study table, replay, bad input."""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.cli import main
from nao_trainer.data import own
from nao_trainer.data.turn_table import COLUMNS, read_table

STUDY = """\
study: {name: own-data}
robot: {url: mock}
session: {turns: 6, practice: false}
timing: {speed: 40}
answers: {input: simulated}
policy: {kind: schedule, schedule: [L1, L2, RF1, L3, RF2, L4]}
eeg: {mode: simulated, processing: {window_s: 0.25, hop_s: 0.05}}
"""


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """Three sessions of `nao-trainer run`: two with a simulated Muse, one with EEG off."""
    root = tmp_path_factory.mktemp("own")
    cfg = root / "study.yaml"
    # no session.xdf here (its recorder's stop costs ~5 s a session): these tests read the CSV record; the
    # resume test below keeps it
    cfg.write_text(STUDY.replace("eeg: {mode: simulated, ", "eeg: {mode: simulated, xdf: false, "))
    out = root / "study"
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    procs = [subprocess.Popen([sys.executable, "-m", "nao_trainer", "run", "--config", str(cfg), "--pseudonym", p,
                               "--seed", str(k), "--out", str(out), "--quiet", *extra], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for k, (p, extra) in enumerate((("P1", []), ("P2", []), ("P3", ["--eeg", "off"])))]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    return out


def _session(study: Path, pseudonym: str) -> Path:
    return next(p for p in study.iterdir() if p.name.startswith(pseudonym + "_"))


def _copy(study: Path, dest: Path, *pseudonyms: str) -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    for p in pseudonyms:
        src = _session(study, p)
        shutil.copytree(src, dest / src.name)
    return dest


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _cli(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


# -- offline == live ----------------------------------------------------------------------------


def test_offline_engagement_from_the_raw_eeg_equals_the_live_values(study):
    for p in ("P1", "P2"):
        phases, notes = own.replay_phases(_session(study, p))
        assert notes == [] and len(phases) == 1 + 2 * 6  # baseline, then listening + answer per turn
        live = [ph for ph in phases if ph.live_engagement is not None]
        assert len(live) >= 10
        for ph in phases:
            assert (ph.engagement is None) == (ph.live_engagement is None), ph
            if ph.engagement is not None:
                assert abs(ph.engagement - ph.live_engagement) <= 1e-9
                assert abs(ph.index - ph.live_index) <= 1e-9


def test_engagement_command_recomputes_a_session_and_a_study(study, capsys):
    folder = _session(study, "P1")
    code, out, _ = _cli(["engagement", str(folder)], capsys)
    assert code == 0
    rows = list(csv.DictReader(out.splitlines()))
    turns = _rows(folder / "turns.csv")
    assert [r["turn"] for r in rows] == [t["turn"] for t in turns]
    for r, t in zip(rows, turns):  # turns.csv keeps 4 decimals of the live value
        assert (r["engagement"] == "") == (t["engagement"] == "")
        if t["engagement"]:
            assert abs(float(r["engagement"]) - float(t["engagement"])) <= 5e-5
    code, out, err = _cli(["engagement", str(study)], capsys)
    rows = list(csv.DictReader(out.splitlines()))
    assert code == 0 and {r["session"].split("_")[0] for r in rows} == {"P1", "P2", "P3"}
    assert all(r["engagement"] == "" and "no eeg/ folder" in r["reason"] for r in rows if r["session"].startswith("P3"))
    code, _, err = _cli(["engagement", str(folder), "--compat", "authors2018"], capsys)
    assert code == 2 and "needs Muse band lines" in err


# -- import, fit, study ---------------------------------------------------------------------------


def test_own_sessions_import_into_the_published_tables_columns_and_encodings(study, tmp_path, capsys):
    code, _, err = _cli(["import", str(study), "--out", str(tmp_path / "t.csv")], capsys)
    assert code == 0, err
    table = read_table(tmp_path / "t.csv")
    assert list(table.columns) == list(COLUMNS) and len(table) == 18
    assert set(table["success"].tolist()) <= {0, 1} and set(table["action"].tolist()) <= set(range(6))
    assert set(table["pseudonym"].tolist()) == {"P1", "P2", "P3"}
    from nao_trainer.core import mdp

    for i in range(len(table)):  # state, its parts and the scores agree as in the published import
        st = mdp.decode(int(table["state"][i]))
        assert (st.length, st.feedback, st.previous) == (table["length"][i], table["feedback"][i],
                                                          table["previous_score"][i])
        ok = bool(table["success"][i])
        assert table["signed_score"][i] == (st.level if ok else -st.level)
    p3 = table["pseudonym"] == "P3"
    assert np.isnan(table["engagement"][p3]).all() and np.isfinite(table["engagement"][~p3]).sum() >= 8
    # the engagement column is the offline recomputation (full precision), equal to the live value
    first = _session(study, "P1")
    live = {int(r["turn"]): r for r in _rows(first / "turns.csv")}
    for i in np.flatnonzero(table["session"] == first.name):
        want = live[int(table["turn"][i])]["engagement"]
        if want:
            assert abs(table["engagement"][i] - float(want)) <= 5e-5
    assert "no eeg/ folder" in err  # P3 had EEG off: said, and imported


def test_study_table_and_figure(study, tmp_path, capsys):
    code, _, err = _cli(["study", str(study), "--out", str(tmp_path)], capsys)
    assert code == 0, err
    rows = _rows(tmp_path / "study.csv")
    assert [r["pseudonym"] for r in rows] == sorted(r["pseudonym"] for r in rows) and len(rows) == 3
    for r in rows:
        turns = _rows(study / r["session"] / "turns.csv")
        assert int(r["turns"]) == 6 and int(r["score"]) == sum(int(t["score"]) for t in turns)
        assert r["status"] == "completed" and r["policy"] == "schedule" and float(r["duration_s"]) > 0
        for level in (1, 2, 3, 4):
            played = [t["success"] == "True" for t in turns if t["level"] == str(level)]
            got = r[f"success_L{level}"]
            assert (got == "") if not played else abs(float(got) - sum(played) / len(played)) < 1e-4
    assert rows[2]["engagement"] == "" and float(rows[0]["engagement"]) > 0
    # how many turns had EEG: as many as have an engagement value (0 for the session with EEG off)
    for r in rows:
        turns = _rows(study / r["session"] / "turns.csv")
        assert int(r["eeg_turns"]) == (0 if r["engagement"] == "" else sum(t["engagement"] != "" for t in turns))
    assert all(r["study"] == "own-data" and r["input"] == "simulated" for r in rows)  # issue 17: said per session
    assert "3 sessions (3 simulated)" in err
    header = (tmp_path / "study.csv").read_text().splitlines()[0].split(",")
    assert header == ["session", "pseudonym", "study", "input", "date", "turns", "score", "success_L1", "success_L2",
                      "success_L3", "success_L4", "engagement", "eeg_turns", "policy", "status", "duration_s",
                      "span", "span_lo", "span_hi", "span_rate"]
    for r in rows:  # the span: the run summary's (session.json), from the same counted turns and the shipped prior
        span = json.loads((study / r["session"] / "session.json").read_text())["span"]
        assert span["rate"] == 0.75 == float(r["span_rate"]) and span["interval"] == 0.9
        got = [float(r[k]) for k in ("span", "span_lo", "span_hi")]
        assert got == pytest.approx([span["median"], span["lo"], span["hi"]], abs=0.006)
        assert got[1] < got[0] < got[2]
    code, _, err = _cli(["study", str(study), "--out", str(tmp_path / "f"), "--no-figure", "--input", "tactile"], capsys)
    assert code == 2 and "the filter left none of the 3 sessions" in err
    code, _, err = _cli(["study", str(study), "--out", str(tmp_path / "g"), "--no-figure", "--study", "own-data"],
                        capsys)
    assert code == 0 and len(_rows(tmp_path / "g" / "study.csv")) == 3
    assert (tmp_path / "study.png").stat().st_size > 10_000


def test_replay_publishes_the_raw_eeg_a_session_saved(study):
    from nao_trainer.eeg.simulated_muse import ReplayMuse

    folder = _session(study, "P1")
    x, _ts, _ = own.read_raw(folder / "eeg" / "raw.csv", 4)
    rep = ReplayMuse.start(folder, source_id=f"replay-own-{os.getpid()}")
    try:
        assert rep.fs == 256.0 and tuple(rep.labels) == ("TP9", "AF7", "AF8", "TP10")
        np.testing.assert_array_equal(rep.data, x)
    finally:
        rep.stop()
    rep = ReplayMuse.start(study, source_id=f"replay-study-{os.getpid()}")  # a study: its sessions in a row
    try:
        firsts = [own.read_raw(_session(study, p) / "eeg" / "raw.csv", 4)[0] for p in ("P1", "P2")]
        assert [b[0].split("/")[0] for b in rep.boundaries] == [_session(study, p).name for p in ("P1", "P2")]
        np.testing.assert_array_equal(rep.data, np.concatenate(firsts))
    finally:
        rep.stop()


# -- bad input ------------------------------------------------------------------------------------


def test_torn_row_missing_eeg_unknown_version_and_left_out_turns(study, tmp_path, capsys):
    root = _copy(study, tmp_path / "bad", "P1", "P2")
    p1, p2 = _session(root, "P1"), _session(root, "P2")
    text = (p1 / "turns.csv").read_text()
    (p1 / "turns.csv").write_text(text[: len(text) - 25])  # a kill in the middle of the last row
    shutil.rmtree(p1 / "eeg")
    rows = (p2 / "turns.csv").read_text().splitlines()
    hdr = rows[0].split(",")
    f = rows[2].split(",")
    f[hdr.index("success")], f[hdr.index("score")], f[hdr.index("signed_score")] = "", "", ""
    f[hdr.index("notes")] = "interrupted: robot lost during await_answer"
    rows[2] = ",".join(f)
    g = rows[3].split(",")
    g[hdr.index("length")] = "9"  # contradicts its state
    rows[3] = ",".join(g)
    h = rows[5].split(",")
    h[hdr.index("invalid")], h[hdr.index("notes")] = "True", "invalid (keys): participant distracted"
    rows[5] = ",".join(h)  # marked invalid by the operator
    (p2 / "turns.csv").write_text("\n".join(rows) + "\n")
    third = _copy(study, tmp_path / "bad", "P3") / _session(study, "P3").name
    info = json.loads((third / "session.json").read_text())
    (third / "session.json").write_text(json.dumps(dict(info, format_version=99)))

    code, _, err = _cli(["import", str(root), "--out", str(tmp_path / "t.csv"), "--no-cache"], capsys)
    assert code == 6  # the table is written; one session was skipped
    lines = [ln for ln in err.splitlines() if ln.startswith("nao-trainer import: ")]
    assert any(f"{third.name}: skipped: " in ln and "format_version 99 is unknown" in ln for ln in lines)
    assert any(f"{p1.name}: turns.csv line 7 torn" in ln for ln in lines)
    assert any(f"{p1.name}: no eeg/ folder" in ln for ln in lines)
    assert any("3 turns left out of the table, kept in their turns.csv (interrupted: 1, invalid: 2)" in ln
               for ln in lines)
    assert any(f"{p2.name} turn 2: interrupted: robot lost during await_answer" in ln for ln in lines)
    assert any(f"{p2.name} turn 3: invalid: length 9 contradicts state" in ln for ln in lines)
    assert any(f"{p2.name} turn 5: invalid: marked by the operator (invalid (keys): participant distracted)" in ln
               for ln in lines)
    table = read_table(tmp_path / "t.csv")
    assert (table["session"] == p1.name).sum() == 5 and (table["session"] == p2.name).sum() == 3
    prov = json.loads((tmp_path / "t.csv.json").read_text())
    assert len(prov["excluded_turns"]) == 3 and len(prov["skipped"]) == 1
    # the study table reads the same folders as far as they are valid
    code, _, err = _cli(["study", str(root), "--no-figure"], capsys)
    assert code == 0 and f"{third.name}: skipped:" in err and len(_rows(root / "study.csv")) == 2


def test_a_root_mixing_both_layouts_imports_both_and_says_so(study, dataset_root, tmp_path, capsys):
    root = _copy(study, tmp_path / "mixed", "P1")
    shutil.copytree(dataset_root / "user_1" / "session_4", root / "user_1" / "session_4")
    code, _, err = _cli(["import", str(root), "--out", str(tmp_path / "t.csv"), "-q"], capsys)
    assert code == 0 and "holds both layouts (1 published, 1 written by `run`)" in err
    table = read_table(tmp_path / "t.csv")
    assert set(table.sessions) == {"user_1/session_4", _session(study, "P1").name}
    assert set(table["pseudonym"].tolist()) == {"user_1", "P1"}
    # issue 17: each row says which study and who answered; the summary says what the table mixes
    assert {(str(s), str(i)) for s, i in zip(table["study"], table["input"])} == {("published", "published"),
                                                                                  ("own-data", "simulated")}
    assert "sessions by study/input: own-data/simulated 1, published/published 1" in err
    code, _, err = _cli(["import", str(root), "--out", str(tmp_path / "c.csv"), "--compat", "authors2018", "-q"],
                        capsys)
    assert code == 6 and "applies to the published layout only" in err  # written, one session skipped


def test_fuzzed_session_files_never_give_a_traceback(study, tmp_path, capsys):
    rng = np.random.default_rng(7)
    targets = ["turns.csv", "session.json", "eeg/phases.csv", "eeg/raw.csv", "eeg/stream.json", "events.jsonl"]
    for case in range(12):
        root = _copy(study, tmp_path / f"fuzz{case}", "P1")
        folder = _session(root, "P1")
        path = folder / targets[case % len(targets)]
        data = bytearray(path.read_bytes())
        how = rng.integers(3)
        if how == 0:
            data = data[: int(rng.integers(0, len(data)))]  # truncated anywhere
        elif how == 1:
            for i in rng.integers(0, len(data), size=8):
                data[i] = int(rng.integers(0, 256))  # bytes flipped
        else:
            data = data.replace(b",", b";", int(rng.integers(1, 5)))  # separators changed
        path.write_bytes(bytes(data))
        for args in (["import", str(root), "--out", str(tmp_path / f"f{case}.csv"), "--no-cache", "-q"],
                     ["engagement", str(root)], ["study", str(root), "--no-figure"]):
            try:
                code = main(args)
            except SystemExit as exc:  # argparse only
                code = exc.code
            out, err = capsys.readouterr()
            assert code in (0, 2, 6), (case, args, err)
            assert "Traceback" not in err and "unexpected" not in err, (case, args, err)
            if code == 2:
                assert len([ln for ln in err.splitlines() if "error" in ln]) == 1, err


def _running(xdf: Path) -> bool:
    """Whether a recorder process writing ``xdf`` still runs (its command line names the file; Linux /proc)."""
    proc = Path("/proc")
    if not proc.is_dir():
        return True  # elsewhere: wait for its "stopped" line (or the limit)
    for cmdline in proc.glob("[0-9]*/cmdline"):
        try:
            if str(xdf).encode() in cmdline.read_bytes():
                return True
        except OSError:  # ended while we looked
            continue
    return False


@pytest.mark.slow
def test_a_killed_and_resumed_session_replays_each_monitor_as_it_ran(tmp_path):
    """`run --resume` appends a second monitor (fresh estimator and scale) to the same eeg/ files."""
    import signal
    import time

    cfg = tmp_path / "study.yaml"
    cfg.write_text(STUDY.replace("turns: 6", "turns: 8").replace("speed: 40", "speed: 25"))  # killed after 3
    out = tmp_path / "s"
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    base = [sys.executable, "-m", "nao_trainer", "run", "--quiet", "--no-keys"]
    proc = subprocess.Popen([*base, "--config", str(cfg), "--pseudonym", "R1", "--seed", "5", "--out", str(out)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    folder = None
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and folder is None:
            found = [p for p in out.glob("R1_*") if (p / "turns.csv").exists() and len(_rows(p / "turns.csv")) >= 3]
            folder = found[0] if found else None
            time.sleep(0.1)
        assert folder is not None
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.communicate(timeout=30)
    log = folder / "eeg" / "xdf.log"
    deadline = time.monotonic() + 90  # the first recorder finishes its file by itself (slower under load) ...
    while time.monotonic() < deadline and "xdf: stopped" not in log.read_text() and _running(folder / "session.xdf"):
        time.sleep(0.2)  # ... or ends without its footers (its stop limit): wait for the process, not for the limit
    res = subprocess.run([*base, "--resume", str(folder)], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    phases, notes = own.replay_phases(folder)
    monitors = {r["monitor_started"] for r in _rows(folder / "eeg" / "phases.csv")}
    assert len(monitors) == 2 and len(_rows(folder / "eeg" / "segments.csv")) == 2 and notes == []
    assert sum(ph.live_engagement is not None for ph in phases) >= 10
    for ph in phases:
        assert (ph.engagement is None) == (ph.live_engagement is None), ph
        if ph.engagement is not None:
            assert abs(ph.engagement - ph.live_engagement) <= 1e-9 and abs(ph.index - ph.live_index) <= 1e-9
    assert (folder / "session.xdf").exists() and (folder / "session_2.xdf").exists()  # the first file kept
    table, excluded = own.table_rows(own.read_session(folder))
    assert sorted({r["turn"] for r in table}) == list(range(1, 9))
