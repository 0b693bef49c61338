"""`study export` replaces only a folder it wrote itself: another BIDS dataset or a folder with a
participants.csv of its own is refused in one line, untouched."""
from __future__ import annotations

import json

import pytest

from _study_data import study_with_one_participant
from nao_trainer.cli import main


@pytest.fixture
def study(tmp_path, capsys):
    root = study_with_one_participant(tmp_path)
    capsys.readouterr()
    return root


FOREIGN = {
    "bids": ("dataset_description.json", json.dumps({"Name": "the lab's archive", "BIDSVersion": "1.9.0",
                                                     "GeneratedBy": [{"Name": "mne-bids"}]})),
    "published": ("participants.csv", "participant_id,age\nsub-01,34\n"),
}


@pytest.mark.parametrize("kind", sorted(FOREIGN))
def test_another_dataset_is_not_replaced(study, tmp_path, capsys, kind):
    name, text = FOREIGN[kind]
    other = tmp_path / "archive"
    (other / "sub-01").mkdir(parents=True)
    (other / name).write_text(text)
    (other / "sub-01" / "data.txt").write_text("irreplaceable")
    code = main(["study", "export", str(study), f"--{kind}", str(other)])
    err = capsys.readouterr().err
    assert code == 2 and "not empty" in err and len(err.strip().splitlines()) == 1, err
    assert (other / "sub-01" / "data.txt").read_text() == "irreplaceable" and (other / name).read_text() == text


@pytest.mark.parametrize("kind", sorted(FOREIGN))
def test_an_earlier_export_is_replaced(study, tmp_path, capsys, kind):
    out = tmp_path / "export"
    for _ in range(2):
        code = main(["study", "export", str(study), f"--{kind}", str(out)])
        assert code == 0, capsys.readouterr().err
