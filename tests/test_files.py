"""The project's file helpers: one-line errors on reads, atomic strict-JSON writes."""
from __future__ import annotations

import json

import pytest

from nao_trainer.errors import DataError
from nao_trainer.files import read_json, write_json_atomic


def test_write_json_refuses_nan_and_leaves_the_old_file(tmp_path):
    path = tmp_path / "x.json"
    write_json_atomic(path, {"rows": [[1.0, 2.5], [3, 4]]})
    assert json.loads(path.read_text()) == {"rows": [[1.0, 2.5], [3, 4]]}
    assert "[1.0, 2.5]" in path.read_text()  # number rows on one line
    with pytest.raises(ValueError):
        write_json_atomic(path, {"v": float("nan")})
    assert json.loads(path.read_text()) == {"rows": [[1.0, 2.5], [3, 4]]}
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]  # no temporary file left


def test_read_json_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match=r"missing.json: gone; do this"):
        read_json(tmp_path / "missing.json", DataError, "gone", "do this")
    with pytest.raises(DataError, match=r"cannot read \(Is a directory\)"):
        read_json(tmp_path, DataError)
    torn = tmp_path / "t.json"
    torn.write_text('{"a": [1,\n 2')
    with pytest.raises(DataError, match=r"t.json:2: not valid JSON .*torn or corrupt"):
        read_json(torn, DataError)


def test_json_format_envelope_round_trip_and_refusals(tmp_path):
    from nao_trainer.files import JsonFormat, canonical_sha256

    fmt = JsonFormat("nao-trainer/thing", 2, "thing file", "thing", "make it again")
    path = tmp_path / "thing.json"
    fmt.write(path, {"b": [1.5, 2], "a": "x"})
    doc = json.loads(path.read_text())
    assert list(doc) == ["format", "format_version", "sha256", "payload"]
    assert doc["sha256"] == canonical_sha256({"a": "x", "b": [1.5, 2]})
    assert fmt.read(path, DataError) == {"b": [1.5, 2], "a": "x"}
    path.write_text(path.read_text().replace('"x"', '"y"'))
    with pytest.raises(DataError, match=r"thing.json: checksum mismatch .*; make it again$"):
        fmt.read(path, DataError)
    with pytest.raises(ValueError, match=r"^src: thing format version 1, this nao-trainer reads 2; make it again$"):
        fmt.check({"format": "nao-trainer/thing", "format_version": 1}, "src", ValueError)
    with pytest.raises(DataError, match=r"src: not a nao-trainer thing file \(format='other'\)"):
        fmt.check({"format": "other"}, "src", DataError)
    with pytest.raises(DataError, match=r"no such thing file; make it again"):
        fmt.read(tmp_path / "missing.json", DataError)
