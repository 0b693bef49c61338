"""Offline per-turn engagement: exact reproduction of the authors' tables, own definitions, raw EEG,
broken recordings, and the `nao-trainer engagement` command."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.data import published as pub
from nao_trainer.cli import main
from nao_trainer.data import engagement as offline
from nao_trainer.errors import DataError


@pytest.fixture(scope="module")
def derived(derived_dir):
    return pub.read_turn_table(derived_dir / "index_1.csv"), pub.read_turn_table(derived_dir / "normalized_1.csv")


def _values(result, attr):
    return np.array([np.nan if getattr(t, attr) is None else getattr(t, attr) for t in result.turns])


def test_authors2018_reproduces_published_tables_for_all_sessions(dataset_root, derived):
    index_tab, norm_tab = derived
    results = offline.session_engagement_many(dataset_root, compat="authors2018", workers=1)
    assert len(results) == 50
    assert {r.session for r in results} == set(index_tab.ids) == set(norm_tab.ids)
    worst = 0.0
    for r in results:
        ref_i = index_tab.session(r.session)["engagement"]
        ref_n = norm_tab.session(r.session)["engagement"]
        assert len(r.turns) == len(ref_i) == 25
        assert [t.turn for t in r.turns] == list(range(1, 26))
        err_i = np.abs(_values(r, "engagement_index") - ref_i).max()
        err_n = np.abs(_values(r, "engagement") - ref_n).max()
        worst = max(worst, err_i, err_n)
    assert worst <= 1e-6  # the README says ~1e-11


def test_authors2018_from_raw_files_only(raw_root, derived):
    index_tab, norm_tab = derived
    sdir = raw_root / "user_30" / "session_1"
    assert not (sdir / "EEG").exists()  # the raw layout: band lines come from robot_N
    r = offline.session_engagement(sdir, compat="authors2018")
    for attr, tab in (("engagement_index", index_tab), ("engagement", norm_tab)):
        np.testing.assert_allclose(_values(r, attr), tab.session(r.session)["engagement"], atol=1e-9, rtol=0)


def test_own_definition_from_bands(dataset_root, raw_root):
    # user_23/session_1: bands plus an intro recording in the raw copy -> intro baseline
    sdir = dataset_root / "user_2" / "session_2"
    r = offline.session_engagement(sdir)
    assert r.source == "bands" and r.compat is None and r.baseline.startswith("session listening phases")
    e, i = _values(r, "engagement"), _values(r, "engagement_index")
    assert np.isfinite(e).all() and ((0 <= e) & (e <= 1)).all() and np.isfinite(i).all()
    assert all(0 <= t.quality <= 1 and 0 <= t.contact <= 1 for t in r.turns)
    # the correct EWMA differs from the authors' lagged one, but both describe the same signal
    a = _values(offline.session_engagement(sdir, compat="authors2018"), "engagement_index")
    assert not np.allclose(i, a) and np.corrcoef(i, a)[0, 1] > 0.9
    with_intro = offline.session_engagement(raw_root / "user_23" / "session_1")
    assert with_intro.baseline == "intro + running bounds" and with_intro.source == "bands"
    assert set(with_intro.series) == set(range(1, 26))


def _strip_to_raw(src: Path, dest: Path) -> Path:
    """A copy of a raw session whose recordings keep only their raw `eeg` lines (and h)."""
    shutil.copytree(src, dest)
    for f in dest.iterdir():
        if f.name.startswith(("robot_", "intro")):
            f.write_text("".join(ln for ln in f.read_text().splitlines(True) if ln.startswith(("eeg ", "h "))))
    shutil.rmtree(dest / "EEG", ignore_errors=True)
    return dest


def test_raw_only_recordings_use_the_online_method(raw_root, tmp_path):
    sdir = _strip_to_raw(raw_root / "user_1" / "session_4", tmp_path / "user_1" / "session_4")
    r = offline.session_engagement(sdir)
    assert r.source == "raw" and r.baseline == "intro + running bounds"
    i, e = _values(r, "engagement_index"), _values(r, "engagement")
    assert np.isfinite(i).all() and np.isfinite(e).all() and ((0 <= e) & (e <= 1)).all()
    assert min(t.quality for t in r.turns) > 0.5
    # the same numbers as forcing --source raw on the full files
    forced = offline.session_engagement(raw_root / "user_1" / "session_4", source="raw")
    np.testing.assert_allclose(_values(forced, "engagement_index"), i)
    # and they follow the Muse's own band powers (Pearson r over turns; 0.87 for this session)
    bands = _values(offline.session_engagement(raw_root / "user_1" / "session_4", source="bands"), "engagement_index")
    assert np.corrcoef(i, bands)[0, 1] > 0.6
    with pytest.raises(Exception, match="drop --source raw"):
        offline.session_engagement(sdir, compat="authors2018", source="raw")


def test_broken_recordings_empty_only_their_turn(dataset_root, derived, tmp_path):
    index_tab, _ = derived
    sdir = tmp_path / "user_4" / "session_2"
    shutil.copytree(dataset_root / "user_4" / "session_2", sdir)
    bad = sdir / "EEG" / "bands_robot_5"
    lines = bad.read_text().splitlines()
    k = [i for i, ln in enumerate(lines) if ln.startswith("b ")][3]
    lines[k] = " ".join(lines[k].split()[:-1])  # drop a value of the 4th 'b' line
    bad.write_text("\n".join(lines) + "\n")
    (sdir / "EEG" / "bands_robot_9").unlink()
    cut = sdir / "EEG" / "bands_robot_12"
    text = cut.read_text()
    cut.write_text(text[: text.index("\nAt ", len(text) // 2) + 6])  # truncated inside an 'At' line
    for compat in ("authors2018", None):
        r = offline.session_engagement(sdir, compat=compat)
        by = {t.turn: t for t in r.turns}
        assert by[5].engagement is None and by[5].engagement_index is None
        assert f"bands_robot_5 line {k + 1}: expected 4 values after 'b', got 3" in by[5].reason
        assert by[9].engagement is None and "robot_9: recording not found" in by[9].reason
        assert by[12].engagement is None and "(the file looks truncated)" in by[12].reason
        assert "expected 4 values after 'At'" in by[12].reason
        others = [t for t in r.turns if t.turn not in (5, 9, 12)]
        assert all(t.engagement is not None and t.reason == "" for t in others)
    # the authors' per-turn index of the intact turns is unchanged
    ref = index_tab.session("user_4/session_2")["engagement"]
    got = _values(offline.session_engagement(sdir, compat="authors2018"), "engagement_index")
    keep = [k for k in range(25) if k not in (4, 8, 11)]
    np.testing.assert_allclose(got[keep], ref[keep], atol=1e-9, rtol=0)


def _synthetic_session(root: Path, good_contact: bool) -> Path:
    """Two turns of 10 Hz band lines; channel TP9 has bad contact (h=4) and absurd beta."""
    sdir = root / "user_900" / "session_1"
    (sdir / "EEG").mkdir(parents=True)
    (sdir / "state_EEG").write_text("3 0 0 robot_1 user_1\n5 0 1 robot_2 user_2\n")
    rng = np.random.default_rng(0)
    for turn, beta in ((1, 0.2), (2, 0.4)):
        lines = []
        for _ in range(50):
            b = beta + rng.normal(0, 0.01, 4)
            b[0] = 0.95  # TP9: nonsense while its contact is bad
            lines += ["a 0.3 0.3 0.3 0.3", "b " + " ".join(f"{v:.4f}" for v in b), "t 0.2 0.2 0.2 0.2"]
            lines.append("h " + ("1 1 1 1" if good_contact else "4 1 2 1"))
        (sdir / "EEG" / f"bands_robot_{turn}").write_text("\n".join(lines) + "\n")
    return sdir


def test_own_definition_excludes_bad_contact(tmp_path):
    r = offline.session_engagement(_synthetic_session(tmp_path / "bad", good_contact=False))
    i = _values(r, "engagement_index")
    # only AF7, AF8, TP10: beta 0.2 / (0.3 + 0.2) = 0.4 and 0.8
    np.testing.assert_allclose(i, [0.4, 0.8], atol=0.01)
    assert [t.contact for t in r.turns] == [0.0, 0.0] and [t.quality for t in r.turns] == [1.0, 1.0]
    e = _values(r, "engagement")
    assert e[0] < 0.1 and e[1] > 0.9
    # with good contact TP9's beta counts
    r2 = offline.session_engagement(_synthetic_session(tmp_path / "good", good_contact=True))
    assert _values(r2, "engagement_index")[0] > 0.6


def test_all_channels_bad_gives_empty_turn_with_reason(tmp_path):
    sdir = _synthetic_session(tmp_path, good_contact=False)
    f = sdir / "EEG" / "bands_robot_2"
    f.write_text(f.read_text().replace("h 4 1 2 1", "h 4 4 4 1"))
    r = offline.session_engagement(sdir)
    assert r.turns[1].engagement is None and r.turns[1].quality == 0.0
    assert "only 0% of samples with >= 2 channels in good contact" in r.turns[1].reason
    assert r.turns[0].engagement_index is not None


def test_cli_csv_json_and_errors(dataset_root, derived, capsys, tmp_path):
    index_tab, _ = derived
    sdir = dataset_root / "user_10" / "session_1"
    assert main(["engagement", str(sdir), "--compat", "authors2018"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "turn,engagement_index,engagement,quality,contact,reason"
    rows = [ln.split(",") for ln in out[1:]]
    assert [int(r[0]) for r in rows] == list(range(1, 26))
    ref = index_tab.session("user_10/session_1")["engagement"]
    np.testing.assert_allclose([float(r[1]) for r in rows], ref, atol=1e-12)
    assert main(["engagement", str(sdir), "--format", "json", "--plot", str(tmp_path / "e.png")]) == 0
    cap = capsys.readouterr()
    data = json.loads(cap.out)
    assert data["session"] == "user_10/session_1" and data["compat"] is None and len(data["turns"]) == 25
    assert set(data["turns"][0]) == {"turn", "engagement_index", "engagement", "quality", "contact", "reason"}
    assert (tmp_path / "e.png").stat().st_size > 10_000 and "figure saved" in cap.err
    # user errors: one line, exit 2, no traceback
    assert main(["engagement", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such folder" in err and "Traceback" not in err
    assert main(["engagement", str(sdir), "--source", "raw"]) == 2
    err = capsys.readouterr().err
    assert "no raw recordings (robot_N) for --source raw; this session has only EEG/bands_* files" in err
    assert main(["engagement", str(sdir), "--fs", "0"]) == 2
    assert "--fs must be > 0" in capsys.readouterr().err


def test_cli_many_sessions_adds_session_column(dataset_root, tmp_path, capsys):
    root = tmp_path / "two"
    for sid in ("user_2/session_2", "user_10/session_1"):
        shutil.copytree(dataset_root / sid, root / sid)
    out = tmp_path / "e.csv"
    assert main(["engagement", str(root), "--out", str(out), "--workers", "1"]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("session,turn,") and len(lines) == 51
    assert lines[1].startswith("user_2/session_2,1,") and lines[26].startswith("user_10/session_1,1,")


def test_answer_phase_and_skipped_sessions(dataset_root, tmp_path, capsys):
    root = tmp_path / "data"
    for sid in ("user_2/session_2", "user_10/session_1"):
        shutil.copytree(dataset_root / sid, root / sid)
    (root / "user_2" / "session_2" / "EEG" / "bands_user_3").unlink()
    r = offline.session_engagement(root / "user_2" / "session_2", answer=True)
    assert r.answer and np.isfinite(_values(r, "answer_index")[[0, 1, 3]]).all()
    assert r.turns[2].answer_index is None and "user_3: recording not found" in r.turns[2].answer_reason
    assert r.turns[2].engagement is not None  # the listening phase of that turn is intact
    # a session whose state_EEG is broken is skipped with a one-line message; the other is printed
    (root / "user_10" / "session_1" / "state_EEG").write_text("7 0 0 robot_1\n")
    assert main(["engagement", str(root), "--answer", "--workers", "1"]) == 0
    cap = capsys.readouterr()
    assert "skipped user_10/session_1: " in cap.err and "state_EEG line 1: expected 5 fields" in cap.err
    lines = cap.out.splitlines()
    assert lines[0].startswith("session,turn,") and len(lines) == 26
    assert lines[0].endswith("answer_index,answer_engagement,answer_quality,answer_reason")
    assert main(["engagement", str(root / "user_2" / "session_2"), "--answer", "--compat", "authors2018"]) == 2
    assert "authors' tables have no answer phase" in capsys.readouterr().err


def test_truncated_intro_falls_back_to_the_session_baseline(raw_root, tmp_path):
    sdir = tmp_path / "user_30" / "session_1"
    shutil.copytree(raw_root / "user_30" / "session_1", sdir)
    text = (sdir / "intro").read_text()
    (sdir / "intro").write_text(text[: text.index("\nb ", 5000) + 8])
    r = offline.session_engagement(sdir)
    assert r.baseline.startswith("session listening phases (intro unusable: ")
    assert "intro line" in r.baseline and "(the file looks truncated)" in r.baseline
    assert all(t.engagement is not None for t in r.turns)


def test_cli_checks_options_and_output_folders_before_computing(dataset_root, tmp_path, capsys, monkeypatch):
    sdir = dataset_root / "user_10" / "session_1"
    root = tmp_path / "two"
    for sid in ("user_2/session_2", "user_10/session_1"):
        shutil.copytree(dataset_root / sid, root / sid)

    def boom(*a, **k):
        raise AssertionError("computed before the options were checked")

    monkeypatch.setattr(offline, "session_engagement_many", boom)
    for argv, msg in (
        ([str(sdir), "--out", str(tmp_path / "missing" / "e.csv")], "missing does not exist"),
        ([str(sdir), "--plot", str(tmp_path / "missing" / "e.png")], "missing does not exist"),
        ([str(root), "--plot", str(tmp_path / "e.png")], "--plot needs a single session folder"),
        ([str(root), "--compat", "authors2018", "--answer"], "authors' tables have no answer phase"),
    ):
        assert main(["engagement", *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and msg in err and "Traceback" not in err
    monkeypatch.undo()
    # the option combination is checked once, not reported per session as a skipped one
    with pytest.raises(DataError, match="drop --source raw"):
        offline.session_engagement_many(root, "authors2018", "raw", workers=1, problems=[])


def test_raw_source_uses_the_live_monitors_processing(tmp_path):
    from nao_trainer.core import engagement as core
    from nao_trainer.core.eeg import CHANNELS, Processing
    from nao_trainer.eeg.simulated_muse import MuseSignal

    live, s = Processing(), offline.OfflineSettings()
    assert (s.raw_a, s.window_s, s.hop_s, s.min_channels, s.min_quality) == (
        live.ewma_a, live.window_s, live.hop_s, live.min_clean_channels, live.min_quality)
    assert s.a == 0.9  # the 10 Hz band lines keep the authors' factor
    x = MuseSignal(np.random.default_rng(3), fs=220.0, n_channels=4).next(220 * 8)
    path = tmp_path / "robot_1"
    path.write_text("".join("eeg " + " ".join(f"{v:.3f}" for v in row) + "\n" for row in x))
    ph = offline._from_raw(pub.read_recording(path, prefixes=("eeg", "h")), s)
    est = core.OnlineEngagement(220.0, 4, live.window_s, live.hop_s, live.ewma_a, core.QualityThresholds(),
                                live.min_clean_channels, channel_names=CHANNELS)
    rec = pub.read_recording(path, prefixes=("eeg",))["eeg"]
    want = [w.index_smoothed for w in est.push(rec, np.arange(len(rec)) / 220.0)]
    np.testing.assert_allclose(ph.smoothed, np.array(want, dtype=float))
