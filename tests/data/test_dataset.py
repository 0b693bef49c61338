"""The importer: published sessions -> one tidy turn table; bad sessions reported, never a traceback."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from _usermodels_data import import_published
from nao_trainer.cli import main
from nao_trainer.core import mdp
from nao_trainer.data.dataset import import_dataset
from nao_trainer.data.turn_table import COLUMNS, read_table, write_table
from nao_trainer.errors import DataError
from nao_trainer.data.published import read_turn_table


@pytest.fixture(scope="module")
def imported(dataset_root, tmp_path_factory):
    return import_published(dataset_root, tmp_path_factory)


def test_all_published_sessions_import(imported, dataset_root):
    t = imported.table
    assert imported.problems == []
    assert len(t.sessions) == 50 and len(t) == 50 * 25
    assert list(t.columns) == list(COLUMNS)
    assert set(t.sessions) == {f"{p.parent.name}/{p.name}" for p in dataset_root.glob("user_*/session_*")}


def test_mdp_columns_are_consistent(imported):
    t = imported.table
    for i in range(len(t)):
        st = mdp.decode(int(t["state"][i]))
        assert (st.length, st.feedback, st.previous) == (t["length"][i], t["feedback"][i], t["previous_score"][i])
    assert np.array_equal(t["level"], mdp.LEVEL[t["state"]])
    ok = t["success"].astype(bool)
    assert np.array_equal(t["score"], np.where(ok, t["level"], -1))  # equation (1)
    assert np.array_equal(t["signed_score"], np.where(ok, t["level"], -t["level"]))
    assert all(len(s) == n for s, n in zip(t["sequence"], t["length"]))
    assert np.array_equal(ok, t["sequence"] == t["response"])


def test_engagement_and_actions_match_the_authors_tables(imported, derived_dir):
    t = imported.table
    norm = read_turn_table(derived_dir / "normalized_1.csv")
    index = read_turn_table(derived_dir / "index_1.csv")
    for sid in t.sessions:
        m = t["session"] == sid
        n, ix = norm.session(sid), index.session(sid)
        np.testing.assert_allclose(t["engagement"][m], n["engagement"], atol=1e-9)
        np.testing.assert_allclose(t["engagement_index"][m], ix["engagement"], atol=1e-9)
        assert np.array_equal(t["length"][m], n["length"])
        # the authors' `action` produced the *next* turn; ours is the action that produced this turn
        assert np.array_equal(t["action"][m][1:], n["action"][:-1])
        assert t["action"][m][0] == t["level"][m][0] - 1
    assert np.all((t["contact"] >= 0) & (t["contact"] <= 1))


def test_csv_round_trip_is_exact(imported, tmp_path):
    path = write_table(imported.table, tmp_path / "turns.csv", imported.provenance)
    back = read_table(path)
    for name, kind in COLUMNS.items():
        if kind is float:
            np.testing.assert_array_equal(back[name], imported.table[name])
        else:
            assert back[name].tolist() == imported.table[name].tolist(), name
    assert back.fingerprint() == imported.table.fingerprint() == imported.provenance["fingerprint"]
    assert (tmp_path / "turns.csv.json").exists()


def test_read_table_names_the_bad_line(tmp_path, imported):
    path = write_table(imported.table, tmp_path / "turns.csv", {})
    lines = path.read_text().splitlines()
    fields = lines[3].split(",")
    fields[list(COLUMNS).index("turn")] = "x" + fields[list(COLUMNS).index("turn")]
    lines[3] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"turns\.csv:4: column 'turn'"):
        read_table(path)


# -- bad data ------------------------------------------------------------------------------------


def _copy(dataset_root: Path, dest: Path, sessions: list[str]) -> Path:
    for sid in sessions:
        shutil.copytree(dataset_root / sid, dest / sid)
    return dest


SAMPLE = ["user_1/session_4", "user_2/session_2", "user_6/session_1", "user_7/session_1", "user_8/session_1"]


@pytest.fixture
def corrupted(dataset_root, tmp_path):
    root = _copy(dataset_root, tmp_path / "data", SAMPLE)
    log = root / SAMPLE[0] / "logfile"  # truncated mid-line
    text = log.read_text()
    log.write_text(text[: len(text) - 40])
    (root / SAMPLE[1] / "state_EEG").unlink()  # missing file
    log = root / SAMPLE[2] / "logfile"  # garbage line
    lines = log.read_text().splitlines()
    lines[6] = "7 5 0 garbage here"
    log.write_text("\n".join(lines) + "\n")
    st = root / SAMPLE[3] / "state_EEG"  # fewer turns than the logfile promises
    st.write_text("\n".join(st.read_text().splitlines()[:20]) + "\n")
    return root


def test_bad_sessions_are_reported_and_the_rest_import(corrupted):
    result = import_dataset(corrupted)
    assert result.table.sessions == [SAMPLE[4]]
    reasons = {p.session: p.reason for p in result.problems}
    assert set(reasons) == set(SAMPLE[:4])
    assert "logfile line 25" in reasons[SAMPLE[0]]
    assert "state_EEG" in reasons[SAMPLE[1]] and "not found" in reasons[SAMPLE[1]]
    assert "logfile line 7" in reasons[SAMPLE[2]]
    assert "20 turns, fewer than the logfile's 25" in reasons[SAMPLE[3]]
    assert all("\n" not in r for r in reasons.values())


def test_cli_import_exit_codes_and_one_line_messages(corrupted, tmp_path, capsys):
    out = tmp_path / "out" / "turns.csv"
    assert main(["import", str(corrupted), "--out", str(out), "-q"]) == 6  # written, but sessions skipped
    err = capsys.readouterr().err
    assert "exit 6: 4 sessions were skipped" in err.splitlines()[-1]
    skipped = [ln for ln in err.splitlines() if "skipped" in ln and "user_" in ln and ":" in ln]
    assert len([ln for ln in skipped if ln.startswith("nao-trainer import: user_")]) == 4
    assert "Traceback" not in err
    assert len(read_table(out)) == 25
    assert main(["import", str(corrupted), "--out", str(out), "-q", "--allow-skipped"]) == 0
    assert "exit 6" not in capsys.readouterr().err
    shutil.rmtree(corrupted / SAMPLE[4])
    assert main(["import", str(corrupted), "--out", str(tmp_path / "none.csv"), "-q", "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert "none of 4 sessions could be imported" in err and "Traceback" not in err
    assert main(["import", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.csv")]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_import_into_an_existing_folder_fails_before_reading_naming_the_folder(tmp_path, capsys):
    """Issue 17: `--out EXISTING_DIR` failed only after reading everything, naming a temp file."""
    missing_root = tmp_path / "nowhere"  # never read: the --out check comes first
    assert main(["import", str(missing_root), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"--out {tmp_path}: is a folder" in err and "turns.csv" in err
    assert "tmp" not in err.replace(str(tmp_path), "") and "no such folder" not in err


def test_cache_reuses_unchanged_sessions_only(dataset_root, tmp_path):
    root = _copy(dataset_root, tmp_path / "data", SAMPLE[:3])
    cache = tmp_path / "cache"
    first = import_dataset(root, compat="authors2018", cache_dir=cache)
    again = import_dataset(root, compat="authors2018", cache_dir=cache)
    assert (first.cached, again.cached) == (0, 3)
    assert again.table.fingerprint() == first.table.fingerprint()
    os.utime(root / SAMPLE[1] / "logfile", ns=(1, 1))  # touched: that session is read again
    third = import_dataset(root, compat="authors2018", cache_dir=cache)
    assert third.cached == 2
    other = import_dataset(root, compat=None, cache_dir=cache)  # another mode never reads the cache
    assert other.cached == 0


def test_raw_layout_imports(raw_root):
    result = import_dataset(raw_root)
    assert result.problems == [] and len(result.table.sessions) == 4 and len(result.table) == 100
    eng = result.table["engagement"]
    assert np.isfinite(eng).mean() > 0.9 and np.nanmin(eng) >= 0 and np.nanmax(eng) <= 1


def test_damaged_files_never_end_in_a_traceback(dataset_root, tmp_path):
    root = _copy(dataset_root, tmp_path / "data", SAMPLE)
    s = [root / sid for sid in SAMPLE]
    (s[0] / "logfile").write_bytes(bytes(range(256)) * 3)  # binary junk
    (s[1] / "state_EEG").write_text("")  # empty
    shutil.rmtree(s[2] / "EEG")  # no recordings at all: imports, without engagement
    (s[3] / "logfile").unlink()
    (s[3] / "logfile").mkdir()  # a folder where a file should be
    bands = s[4] / "EEG" / "bands_robot_3"
    bands.write_text("a 0.1 0.2\nb x y z w\n" + "\0" * 50)  # garbage band lines: that turn has no engagement
    result = import_dataset(root, compat="authors2018")
    reasons = {p.session: p.reason for p in result.problems}
    assert set(reasons) == {SAMPLE[0], SAMPLE[1], SAMPLE[3]}
    assert "not a text file" in reasons[SAMPLE[0]] or "line 1" in reasons[SAMPLE[0]]
    t = result.table
    assert set(t.sessions) == {SAMPLE[2], SAMPLE[4]}
    assert np.isnan(t["engagement"][t["session"] == SAMPLE[2]]).all()
    row = (t["session"] == SAMPLE[4]) & (t["turn"] == 3)
    assert np.isnan(t["engagement"][row]).all() and "bands_robot_3" in t["eeg_note"][row][0]
    assert np.isfinite(t["engagement"][(t["session"] == SAMPLE[4]) & (t["turn"] != 3)]).all()


def test_unusable_cache_folder_only_warns(dataset_root, tmp_path, capsys):
    root = _copy(dataset_root, tmp_path / "data", SAMPLE[:1])
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    result = import_dataset(root, cache_dir=blocker / "cache")
    assert len(result.table.sessions) == 1 and result.cached == 0
    assert "import cache" in capsys.readouterr().err


def test_robot_feedback_out_of_range_names_the_turn(dataset_root, tmp_path):
    root = _copy(dataset_root, tmp_path / "data", SAMPLE[:2])
    sdir = root / SAMPLE[0]
    for name, col in (("logfile", 2), ("state_EEG", 1)):  # rf = 3 on turn 1, consistently in both files
        lines = (sdir / name).read_text().splitlines()
        fields = lines[0].split(" ")
        fields[col] = "3"
        lines[0] = " ".join(fields)
        (sdir / name).write_text("\n".join(lines) + "\n")
    result = import_dataset(root)
    assert result.table.sessions == [SAMPLE[1]]
    [problem] = result.problems
    assert problem.session == SAMPLE[0]
    assert problem.reason == "logfile turn 1: robot feedback (rf) must be 0, 1 or 2, got 3"


def test_cache_key_follows_the_engagement_definition(dataset_root, tmp_path, monkeypatch):
    import dataclasses

    import nao_trainer
    from nao_trainer.data import engagement as offline

    root = _copy(dataset_root, tmp_path / "data", SAMPLE[:1])
    cache = tmp_path / "cache"
    assert import_dataset(root, cache_dir=cache).cached == 0
    assert import_dataset(root, cache_dir=cache).cached == 1
    monkeypatch.setattr(nao_trainer, "__version__", nao_trainer.__version__ + ".post1")
    assert import_dataset(root, cache_dir=cache).cached == 0  # another release: read again
    assert import_dataset(root, cache_dir=cache).cached == 1
    defaults = offline.OfflineSettings()
    monkeypatch.setattr(offline, "OfflineSettings", lambda: dataclasses.replace(defaults, a=0.8))
    assert import_dataset(root, cache_dir=cache).cached == 0  # other engagement settings: read again
