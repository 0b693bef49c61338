"""A bare `run` never writes into a study folder: a participant's sessions go through `study next`."""
from __future__ import annotations

import pytest

from _study_data import study_with_one_participant
from nao_trainer.cli import main
from nao_trainer.study.registry import study_holding


@pytest.fixture
def study(tmp_path, capsys):
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    return root


def _tree(root):
    return sorted(p.relative_to(root) for p in root.rglob("*"))


@pytest.mark.parametrize("out", ["sessions", ".", "sessions/participants"])
def test_a_bare_run_into_a_study_folder_is_refused_in_one_line(study, tmp_path, capsys, out):
    before = _tree(study)
    code = main(["run", "--config", str(tmp_path / "base.yaml"), "--out", str(study / out), "--pseudonym", "P001",
                 "--no-keys", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert f"nao-trainer study next {study.resolve()} PSEUDONYM" in err
    assert _tree(study) == before


def test_a_bare_resume_of_a_study_session_is_refused(study, capsys):
    folder = study / "sessions" / "P001_20261102-100000"
    folder.mkdir()
    before = _tree(study)
    code = main(["run", "--resume", str(folder)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "PSEUDONYM --resume" in err, err
    assert _tree(study) == before


def test_a_run_outside_the_study_still_runs(study, tmp_path, capsys):
    code = main(["run", "--config", str(tmp_path / "base.yaml"), "--out", str(tmp_path / "elsewhere"),
                 "--pseudonym", "P001", "--no-keys", "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert any((tmp_path / "elsewhere").glob("P001_*")) and not any((study / "sessions").glob("P001_*"))


def test_study_holding_finds_the_study_from_inside_only(study, tmp_path):
    assert study_holding(study / "sessions" / "x" / "y") == study.resolve()
    assert study_holding(tmp_path) is None
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "registry.json").write_text('{"format": "something else"}')
    assert study_holding(tmp_path / "other" / "sessions") is None
