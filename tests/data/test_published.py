"""Readers of the published dataset layout, on the real data and on broken copies."""
import shutil

import numpy as np
import pytest

from nao_trainer.data import published as pub
from nao_trainer.errors import DataError


def test_find_sessions_natural_order(dataset_root):
    sessions = pub.find_sessions(dataset_root)
    ids = [pub.session_id(s) for s in sessions]
    assert len(ids) == 50 and len(set(ids)) == 50
    users = [int(i.split("/")[0].split("_")[1]) for i in ids]
    assert users == sorted(users)  # user_2 before user_10
    assert ids[0] == "user_1/session_4" and ids[1] == "user_1/session_5"
    # a session folder is its own single session; the parent of clean_data works too
    assert pub.find_sessions(sessions[3]) == [sessions[3]]
    assert len(pub.find_sessions(dataset_root.parent)) == 50


def test_session_id_of_a_relative_path(dataset_root, monkeypatch):
    monkeypatch.chdir(dataset_root / "user_10" / "session_1")
    assert pub.session_id(pub.find_sessions(pub.Path("."))[0]) == "user_10/session_1"


def test_find_sessions_errors(tmp_path):
    with pytest.raises(DataError, match="no such folder"):
        pub.find_sessions(tmp_path / "missing")
    with pytest.raises(DataError, match="no sessions found"):
        pub.find_sessions(tmp_path)


def test_logfile_and_state_match_the_derived_table(dataset_root, derived_dir):
    table = pub.read_turn_table(derived_dir / "index_1.csv")
    for sdir in pub.find_sessions(dataset_root)[::7]:
        log = pub.read_logfile(sdir / "logfile")
        states = pub.read_state_eeg(sdir / "state_EEG")
        ref = table.session(pub.session_id(sdir))
        assert len(log) == len(states) == len(ref["length"]) == 25
        assert [r.turn for r in log] == list(range(1, 26))
        assert [r.length for r in log] == [s.length for s in states] == ref["length"].astype(int).tolist()
        assert [s.rf for s in states] == ref["robot_feedback"].astype(int).tolist()
        assert [s.previous_score for s in states] == ref["previous_score"].astype(int).tolist()
        assert [r.score for r in log] == ref["current_score"].astype(int).tolist()
        assert [s.robot_file for s in states] == [f"robot_{k}" for k in range(1, 26)]
        for r in log:
            assert len(r.sequence) == r.length and set(r.sequence) <= {"a", "b", "c"}
            assert r.success in (1, -1) and r.reaction_time <= r.completion_time


def test_raw_recording_and_band_file_agree(raw_root, dataset_root):
    raw = pub.read_recording(raw_root / "user_1" / "session_4" / "robot_1")
    bands = pub.read_recording(dataset_root / "user_1" / "session_4" / "EEG" / "bands_robot_1")
    assert raw.has_raw_eeg and not bands.has_raw_eeg
    assert raw["eeg"].shape[1] == 4 and 700 < raw["eeg"].mean() < 1000
    for p in ("a", "b", "d", "g", "t", "h", "Aa", "ts"):
        np.testing.assert_array_equal(raw[p], bands[p])
    np.testing.assert_array_equal(raw["c"], bands["c"])  # 1 value in raw, padded to 4 in band files
    assert raw["c"].ndim == 1
    # the relative bands sum to ~1 per channel
    rel = sum(raw[p] for p in pub.RELATIVE_BANDS)
    np.testing.assert_allclose(rel, 1.0, atol=1e-3)
    only = pub.read_recording(raw_root / "user_1" / "session_4" / "robot_1", prefixes=("a", "b", "t"))
    assert set(only.data) == {"a", "b", "t"}
    assert only.bands().shape == (len(raw["a"]), 3, 4)


def test_off_by_one_prefix_counts_are_tolerated(tmp_path):
    lines = []
    for i in range(5):
        for p in ("a", "b", "t", "h"):
            if p == "t" and i == 4:
                continue  # one 't' line fewer, as in some published files
            lines.append(f"{p} {i} {i} {i} {i}")
    f = tmp_path / "bands_robot_1"
    f.write_text("\n".join(lines) + "\n")
    rec = pub.read_recording(f)
    assert len(rec["a"]) == 5 and len(rec["t"]) == 4
    assert rec.bands(("t", "a", "b")).shape == (4, 3, 4)


@pytest.mark.parametrize(
    "bad, message",
    [
        ("b 0.1 0.2 0.3", "robot_7 line 3: expected 4 values after 'b', got 3"),
        ("b 0.1 0.2 x 0.4", "robot_7 line 3: 'b' value 'x' is not a number"),
        ("c", "robot_7 line 3: expected 1 values after 'c', got 0"),
    ],
)
def test_malformed_recording_names_file_and_line(tmp_path, bad, message):
    f = tmp_path / "robot_7"
    f.write_text(f"a 1 2 3 4\nb 1 2 3 4\n{bad}\nt 1 2 3 4\n")
    with pytest.raises(DataError) as err:
        pub.read_recording(f)
    assert str(err.value) == f"{tmp_path}/{message}"


def test_truncated_recording_is_named(tmp_path, raw_root):
    src = raw_root / "user_30" / "session_1" / "robot_3"
    text = src.read_text()
    f = tmp_path / "robot_3"
    f.write_text(text[: len(text) // 2].rsplit(" ", 1)[0])  # cut inside a line
    n_lines = f.read_text().count("\n") + 1
    with pytest.raises(DataError, match=rf"robot_3 line {n_lines}: expected 4 values .* \(the file looks truncated\)"):
        pub.read_recording(f)


def test_malformed_logfile_and_state(tmp_path, dataset_root):
    sdir = dataset_root / "user_1" / "session_4"
    log = (sdir / "logfile").read_text().splitlines()
    log[4] = log[4].replace("[", "(", 1)
    (tmp_path / "logfile").write_text("\n".join(log))
    with pytest.raises(DataError, match=r"logfile line 5: expected 7 numbers and two lists"):
        pub.read_logfile(tmp_path / "logfile")
    log = (sdir / "logfile").read_text().splitlines()
    log[1] = "2 seven" + log[1][3:]
    (tmp_path / "logfile").write_text("\n".join(log))
    with pytest.raises(DataError, match=r"logfile line 2: length must be a number, got 'seven'"):
        pub.read_logfile(tmp_path / "logfile")
    (tmp_path / "state_EEG").write_text("7 0 0 robot_1 user_1\n7 1 robot_2 user_2\n")
    with pytest.raises(DataError, match=r"state_EEG line 2: expected 5 fields"):
        pub.read_state_eeg(tmp_path / "state_EEG")
    with pytest.raises(DataError, match="file not found"):
        pub.read_state_eeg(tmp_path / "nothing")
    shutil.copy(sdir / "logfile", tmp_path / "logfile")
    assert len(pub.read_logfile(tmp_path / "logfile")) == 25


def test_turn_table(derived_dir, tmp_path):
    t = pub.read_turn_table(derived_dir / "normalized_1.csv")
    assert len(t.ids) == 1250 and set(t.columns) >= {"length", "engagement", "action"}
    (tmp_path / "x.csv").write_text("ID a b\nu/s 1 2\nu/s 3\n")
    with pytest.raises(DataError, match="x.csv line 3: expected 3 columns, got 2"):
        pub.read_turn_table(tmp_path / "x.csv")


def test_recording_tolerates_tabs_and_crlf(tmp_path):
    f = tmp_path / "robot_1"
    f.write_bytes(b"a\t1 2 3 4\r\nb 1  2 3 4\r\nc 0.5\r\n\r\n")
    rec = pub.read_recording(f)
    assert rec["a"].tolist() == [[1, 2, 3, 4]] and rec["b"].shape == (1, 4) and rec["c"].tolist() == [0.5]
