"""`study power` without usable data says what to give, in one line, before loading anything."""
from __future__ import annotations

import pytest

from _study_data import write_protocol
from nao_trainer.cli import main


def _power(tmp_path, capsys, *extra: str) -> tuple[int, str]:
    code = main(["study", "power", str(write_protocol(tmp_path)), "--reps", "2", "--n", "6",
                 "--out", str(tmp_path / "power"), *extra])
    err = capsys.readouterr().err
    assert "Traceback" not in err and not (tmp_path / "power").exists()
    return code, err


def test_sessions_users_without_data_name_the_flags_power_has(tmp_path, capsys):
    code, err = _power(tmp_path, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "--data ROOT" in err and "--users clusters" in err and "give the root as --users" not in err


@pytest.mark.parametrize("users", ["sessions", "clusters"])
def test_a_folder_of_archives_is_refused_with_how_to_extract_it(tmp_path, capsys, users):
    archives = tmp_path / "sequence-learning"
    archives.mkdir()
    (archives / "clean_data_bands.tar.xz").write_bytes(b"")
    code, err = _power(tmp_path, capsys, "--users", users, "--data", str(archives))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "extract one first" in err, err
