"""The project's file helpers: one-line errors on reads, atomic strict-JSON writes."""
from __future__ import annotations

import json

import pytest

from nao_trainer.errors import DataError
from nao_trainer.files import json_text, read_json, write_json_atomic


def test_write_json_refuses_nan_and_leaves_the_old_file(tmp_path):
    path = tmp_path / "x.json"
    write_json_atomic(path, {"rows": [[1.0, 2.5], [3, 4]]})
    assert json.loads(path.read_text()) == {"rows": [[1.0, 2.5], [3, 4]]}
    assert "[1.0, 2.5]" in path.read_text()  # number rows on one line
    with pytest.raises(ValueError):
        write_json_atomic(path, {"v": float("nan")})
    assert json.loads(path.read_text()) == {"rows": [[1.0, 2.5], [3, 4]]}
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]  # no temporary file left


def _dumps_with_rows_joined(data) -> str:
    """The layout json_text keeps: json.dumps(indent=1), each list of numbers only then joined on one line."""
    def join(value):
        if isinstance(value, dict):
            return {k: join(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            if value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                return "\x00[" + ", ".join(json.dumps(v) for v in value) + "]\x00"
            return [join(v) for v in value]
        return value
    return json.dumps(join(data), indent=1).replace('"\\u0000', "").replace('\\u0000"', "")


@pytest.mark.parametrize("data", [
    {"rows": [[1.0, 2.5, -0.0, 1e300, 3], [True, 1], [], {}], "é\n\"": None, 1: {"x": [None, "s"]}, 2.5: False},
    [[[1, 2], [3]], [], "[1,2]", {"k": [{"v": [0.1, 7]}]}, 12345678901234567890],
    {}, [], "text", 3, None,
])
def test_json_text_is_json_dumps_indented_with_number_rows_on_one_line(data):
    assert json_text(data) == _dumps_with_rows_joined(data)
    assert json.loads(json_text(data)) == json.loads(json.dumps(data))


def test_json_text_keeps_a_string_that_looks_like_a_row_and_refuses_what_json_refuses():
    assert json.loads(json_text({"note": "see [1,2]"})) == {"note": "see [1,2]"}  # a regex over the text did not
    for bad in ({"v": [float("inf")]}, {"v": float("-inf")}, {(1, 2): 3}, {"v": object()}):
        with pytest.raises((ValueError, TypeError)):
            json_text(bad)


def test_read_json_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match=r"missing.json: gone; do this"):
        read_json(tmp_path / "missing.json", DataError, "gone", "do this")
    with pytest.raises(DataError, match=r"cannot read \(Is a directory\)"):
        read_json(tmp_path, DataError)
    torn = tmp_path / "t.json"
    torn.write_text('{"a": [1,\n 2')
    with pytest.raises(DataError, match=r"t.json:2: not valid JSON .*torn or corrupt"):
        read_json(torn, DataError)


@pytest.mark.parametrize("text, message", [
    ("session:\n  seed: 1\neeg:\n  required: true\nsession:\n  turns: 3\n",
     r"y.yaml:5: key 'session' is given twice \(first on line 1\)"),
    ("a:\n  b: 1\n  b: 2\n", r"y.yaml:3: key 'a.b' is given twice \(first on line 2\)"),
    ("a:\n  - {x: 1, x: 2}\n", r"y.yaml:2: key 'a\[0\].x' is given twice"),
    ("session: {seed: !!int notanumber}\n", r"y.yaml:1: !!int 'notanumber' cannot be read"),
    ("x: 1\ny: !!float abc\n", r"y.yaml:2: !!float 'abc' cannot be read"),
    ("b: !!bool maybe\n", r"y.yaml:1: !!bool 'maybe' cannot be read"),
    ("t: !!timestamp 2020-13-45\n", r"y.yaml:1: !!timestamp '2020-13-45' cannot be read \(month must be in 1..12\)"),
    ("a: 1\nb: \x01x\n", r"y.yaml:2: control character U\+0001 is not allowed in YAML; remove it"),
    ("a: 1\nb: 'x\x07'\n", r"y.yaml:2: control character U\+0007"),
    ("a: 1\n\n\x00", r"y.yaml:3: control character U\+0000"),
    ("a: [1,\n  2\n", r"y.yaml:3: not valid YAML"),
    # libyaml stops at its nesting limit; the pure-Python parser recurses until Python stops it
    ("a: " + "[" * 5000 + "]" * 5000 + "\n",
     r"y.yaml(: nested too deeply|:1: not valid YAML \(exceeded maximum nesting depth\))"),
])
def test_read_yaml_refuses_bad_files_in_one_line_with_file_and_line(tmp_path, text, message):
    from nao_trainer.errors import ConfigError
    from nao_trainer.files import read_yaml

    path = tmp_path / "y.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message) as info:
        read_yaml(path)
    assert "\n" not in str(info.value)


def test_read_yaml_keeps_merge_keys_and_records_lines(tmp_path):
    from nao_trainer.files import read_yaml

    path = tmp_path / "ok.yaml"
    path.write_text("base: &b {x: 1}\nother:\n  <<: *b\n  y: 2\nlist: [1, {c: 2}]\n")
    data, lines, _ = read_yaml(path)
    assert data == {"base": {"x": 1}, "other": {"x": 1, "y": 2}, "list": [1, {"c": 2}]}
    assert lines["other.y"] == 4 and lines["list"] == 5
    (tmp_path / "bin.yaml").write_bytes(b"a: 1\nb: \xff\n")
    from nao_trainer.errors import ConfigError

    with pytest.raises(ConfigError, match=r"bin.yaml:2: not a text file"):
        read_yaml(tmp_path / "bin.yaml")


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
