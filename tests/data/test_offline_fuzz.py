"""Seeded fuzzing of session folders: `import`, `study`, `engagement` and `fit` end in one line or succeed.

A real session written by `nao-trainer run` (simulated participant and Muse) and a published session
are copied and mutated, one file each time: a poisoned value (NaN, infinity, a 23-digit or negative
number, text, a path leaving the folder, a NUL), a torn or cut file, a garbage or duplicated line, a
JSON value of the wrong type or nested 100 000 deep, bytes that are not UTF-8, a sparse file larger
than any session writes. Every command is called as the CLI calls it (``nao_trainer.cli.main``): an
exception escaping it (a traceback), an exit code other than 0 / 2 / 6 (import: written, but a
session skipped), or an error of more than one line fails the test. ``python
tests/data/test_offline_fuzz.py 200`` runs a larger batch and prints what each case gave.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

N_SUITE = 40
POISON = ("nan", "NaN", "inf", "-inf", "1e309", "12345678901234567890123", "-5", "0", "", "yes", "x",
          "../../../../etc/passwd", "/etc/passwd", "\x00", "[]", "{}", "\"", "é", "9" * 400, "True")
JSON_POISON = ([], {}, None, "x", float("inf"), -1, 10**30, [[[]]], True)
#: Every file is read by at least one command; these are the ones the commands read.
OWN_FILES = ("turns.csv", "session.json", "eeg/stream.json", "eeg/phases.csv", "eeg/raw.csv", "eeg/segments.csv")
PUB_FILES = ("logfile", "state_EEG")
STUDY = """\
study: {name: fuzz}
robot: {url: mock}
session: {turns: 4, practice: false}
timing: {speed: 50}
answers: {input: simulated}
policy: {kind: schedule, schedule: [L1, L2, RF1, L3]}
eeg: {mode: simulated, xdf: false, processing: {window_s: 0.25, hop_s: 0.05}}  # the fuzzed files are the CSV record
"""


def _own_session(where: Path) -> Path:
    cfg = where / "study.yaml"
    cfg.write_text(STUDY)
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(cfg), "--pseudonym", "F1",
                          "--seed", "1", "--out", str(where / "study"), "--quiet"], capture_output=True, text=True,
                         timeout=120, env=dict(os.environ, QI_LOG_LEVEL="silent"))
    assert res.returncode == 0, res.stderr
    return next((where / "study").iterdir())


@pytest.fixture(scope="module")
def sources(tmp_path_factory, dataset_root) -> dict[str, Path]:
    return {"own": _own_session(tmp_path_factory.mktemp("fuzz-own")),
            "pub": dataset_root / "user_1" / "session_4"}


# -- mutations ----------------------------------------------------------------------------------


def _poison_cell(text: str, rng: np.random.Generator) -> str:
    """One field of one line (comma- or space-separated) replaced by a poison value."""
    lines = text.split("\n")
    body = [i for i, ln in enumerate(lines) if ln.strip()][1 if "," in text else 0:] or [0]
    i = int(rng.choice(body))
    sep = "," if "," in lines[i] else " "
    cells = lines[i].split(sep)
    cells[int(rng.integers(len(cells)))] = str(rng.choice(POISON))
    lines[i] = sep.join(cells)
    return "\n".join(lines)


def _poison_json(text: str, rng: np.random.Generator) -> str:
    data = json.loads(text)
    if isinstance(data, dict) and data and rng.random() < 0.8:
        key = str(rng.choice(sorted(data)))
        data[key] = JSON_POISON[int(rng.integers(len(JSON_POISON)))]
        return json.dumps(data)
    return json.dumps(JSON_POISON[int(rng.integers(len(JSON_POISON)))])


def _line_edit(text: str, rng: np.random.Generator) -> str:
    lines = text.split("\n")
    i = int(rng.integers(1, max(2, len(lines))))
    kind = rng.integers(3)
    if kind == 0:
        lines.insert(i, str(rng.choice(["garbage,,", "\x00\x01", "1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19,20,"
                                        "21,22,23,24,25,26,27", "a b c"])))
    elif kind == 1 and i < len(lines):
        lines.insert(i, lines[i])
    elif i < len(lines):
        del lines[i]
    return "\n".join(lines)


def mutate(folder: Path, files: tuple[str, ...], rng: np.random.Generator) -> str:
    """Damage one file of ``folder``; returns what was done."""
    name = str(rng.choice([f for f in files if (folder / f).is_file()]))
    path = folder / name
    kind = int(rng.integers(7))
    if kind == 0 and name.endswith(".json"):
        path.write_text(_poison_json(path.read_text(), rng))
        what = "json value"
    elif kind in (0, 1, 2):
        path.write_text(_poison_cell(path.read_text(), rng))
        what = "poisoned cell"
    elif kind == 3:
        path.write_text(_line_edit(path.read_text(), rng))
        what = "line edit"
    elif kind == 4:
        size = path.stat().st_size
        os.truncate(path, int(rng.integers(0, max(1, size))))
        what = "cut"
    elif kind == 5:
        path.write_bytes(str(rng.choice(["", "[" * 100_000, "\xff\xfe garbage", "null"])).encode("latin-1"))
        what = "replaced"
    else:
        os.truncate(path, 700_000_000)  # sparse: larger than any session writes, instant to make
        what = "huge"
    return f"{name}: {what}"


# -- running the commands -----------------------------------------------------------------------


def run_commands(root: Path, work: Path, own: bool) -> list[tuple[str, int | str, str]]:
    """(command, exit code or the escaping exception, stderr) of each offline command on ``root``."""
    from nao_trainer.cli import main

    work.mkdir(parents=True, exist_ok=True)
    commands = [["import", str(root), "--out", str(work / "t.csv"), "--no-cache", "-q"],
                ["engagement", str(root), "--out", str(work / "e.csv")],
                ["fit", str(root), "--out", str(work / "fit"), "--no-figures", "--no-cache", "--k", "1"]]
    if own:
        commands.append(["study", str(root), "--no-figure", "--out", str(work / "s")])
    out = []
    for argv in commands:
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code: int | str = main(argv)
        except BaseException as exc:  # noqa: BLE001 - what the test looks for
            code = f"{type(exc).__name__}: {exc}"[:300]
        out.append((argv[0], code, err.getvalue()))
    return out


def problems_of(results: list[tuple[str, int | str, str]]) -> list[str]:
    bad = []
    for cmd, code, err in results:
        errors = [ln for ln in err.splitlines() if ": error: " in ln]
        if isinstance(code, str):
            bad.append(f"{cmd}: traceback {code}")
        elif code not in (0, 2, 6) or (cmd != "import" and code == 6):
            bad.append(f"{cmd}: exit {code}")
        elif code == 2 and len(errors) != 1:
            bad.append(f"{cmd}: exit 2 with {len(errors)} error lines")
        elif "Traceback" in err:
            bad.append(f"{cmd}: traceback printed")
    return bad


def fuzz_case(sources: dict[str, Path], work: Path, seed: int) -> tuple[str, list[tuple[str, int | str, str]]]:
    rng = np.random.default_rng(seed)
    layout = "own" if seed % 3 else "pub"
    shutil.rmtree(work, ignore_errors=True)
    src = sources[layout]
    folder = work / "root" / ("user_1" if layout == "pub" else "") / src.name
    shutil.copytree(src, folder)
    what = mutate(folder, OWN_FILES if layout == "own" else PUB_FILES, rng)
    return f"{layout} {what}", run_commands(work / "root", work / "out", layout == "own")


def test_fuzzed_session_folders_end_in_one_line_or_succeed(sources, tmp_path):
    failures = []
    for seed in range(N_SUITE):
        what, results = fuzz_case(sources, tmp_path / "w", seed)
        bad = problems_of(results)
        if bad:
            failures.append(f"seed {seed} ({what}): {'; '.join(bad)}")
    assert not failures, "\n".join(failures)


# -- the crafted cases of issue 17, each by name ---------------------------------------------------


def _csv_set(path: Path, row: int, column: str, value: str) -> None:
    import csv

    rows = list(csv.reader(io.StringIO(path.read_text())))
    rows[row][rows[0].index(column)] = value
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    path.write_text(buf.getvalue())


def _line_set(path: Path, index: int, field: int, value: str) -> None:
    lines = path.read_text().split("\n")
    f = lines[index].split()
    f[field] = value
    lines[index] = " ".join(f)
    path.write_text("\n".join(lines))


def _stream_json(d: Path, **changes) -> None:
    path = d / "eeg" / "stream.json"
    path.write_text(json.dumps(dict(json.loads(path.read_text()), **changes)))


CRAFTED = {
    "own": {
        "phases NaN": lambda d: _csv_set(d / "eeg" / "phases.csv", 2, "t_begin", "nan"),
        "phases t_begin > t_end": lambda d: _csv_set(d / "eeg" / "phases.csv", 2, "t_begin", "1e12"),
        "stream.json = []": lambda d: (d / "eeg" / "stream.json").write_text("[]"),
        "scalp_channels mismatch": lambda d: _stream_json(d, scalp_channels=["TP9", "AF7"]),
        "session.json nested 100000 deep": lambda d: (d / "session.json").write_text("[" * 100_000 + "]" * 100_000),
        "turn of 23 digits": lambda d: _csv_set(d / "turns.csv", 1, "turn", "12345678901234567890123"),
        "turn -5": lambda d: _csv_set(d / "turns.csv", 1, "turn", "-5"),
        "invalid=yes": lambda d: _csv_set(d / "turns.csv", 1, "invalid", "yes"),
        "huge turns.csv": lambda d: os.truncate(d / "turns.csv", 1 << 30),
        "huge raw.csv": lambda d: os.truncate(d / "eeg" / "raw.csv", 1 << 30),
        "raw.csv inf": lambda d: _csv_set(d / "eeg" / "raw.csv", 5, "lsl_time", "inf"),
    },
    "pub": {
        "logfile inf": lambda d: _line_set(d / "logfile", 0, 0, "inf"),
        "logfile turn of 23 digits": lambda d: _line_set(d / "logfile", 0, 0, "12345678901234567890123"),
        "logfile turn -5": lambda d: _line_set(d / "logfile", 0, 0, "-5"),
        "state_EEG NaN": lambda d: _line_set(d / "state_EEG", 0, 0, "nan"),
    },
}


@pytest.mark.parametrize("layout,case", [(k, c) for k, cases in CRAFTED.items() for c in cases])
def test_each_crafted_case_of_the_issue_ends_in_one_line_or_imports(sources, tmp_path, layout, case):
    src = sources[layout]
    folder = tmp_path / "root" / ("user_1" if layout == "pub" else "") / src.name
    shutil.copytree(src, folder)
    CRAFTED[layout][case](folder)
    results = run_commands(tmp_path / "root", tmp_path / "out", layout == "own")
    assert problems_of(results) == []
    for cmd, code, err in results:
        assert "unexpected" not in err and "Error:" not in err, (cmd, err)  # named, not an exception's text


@pytest.mark.parametrize("case", ["turn of 23 digits", "turn -5", "invalid=yes"])
def test_a_bad_turn_is_left_out_with_its_reason_and_the_others_import(sources, tmp_path, case):
    from nao_trainer.data.dataset import import_dataset

    folder = tmp_path / "root" / sources["own"].name
    shutil.copytree(sources["own"], folder)
    CRAFTED["own"][case](folder)
    result = import_dataset(tmp_path / "root")
    assert len(result.table) == 3 and 1 not in result.table["turn"].tolist()
    (excl,) = result.excluded
    assert excl.reason.startswith("invalid: ")


def test_a_garbage_line_keeps_the_sessions_good_turns(sources, tmp_path):
    from nao_trainer.data.dataset import import_dataset

    folder = tmp_path / "root" / sources["own"].name
    shutil.copytree(sources["own"], folder)
    lines = (folder / "turns.csv").read_text().split("\n")
    lines.insert(2, "garbage,,")
    (folder / "turns.csv").write_text("\n".join(lines))
    result = import_dataset(tmp_path / "root")
    assert result.table["turn"].tolist() == [1, 2, 3, 4] and result.problems == []
    assert any("turns.csv:3: expected" in n and "line left out" in n for n in result.notes), result.notes


def test_a_recording_name_leaving_the_session_folder_is_refused_never_opened(sources, tmp_path):
    folder = tmp_path / "root" / "user_1" / "session_4"
    shutil.copytree(sources["pub"], folder)
    outside = tmp_path / "secret"
    outside.write_text("eeg 1 2 3 4\n")
    lines = (folder / "state_EEG").read_text().split("\n")
    f = lines[0].split()
    lines[0] = " ".join(f[:3] + ["../../../secret", f[4]])
    (folder / "state_EEG").write_text("\n".join(lines))
    results = run_commands(tmp_path / "root", tmp_path / "out", own=False)
    for cmd, code, err in results:
        assert code == 2 and "recording name '../../../secret' must be a file name in the session folder" in err, (cmd, err)


if __name__ == "__main__":  # a larger batch: python tests/data/test_offline_fuzz.py 200
    import tempfile

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        shared = Path(os.environ.get("NAO_TRAINER_SHARED", Path(__file__).resolve().parents[3] / "shared"))
        subprocess.run(["tar", "-xJf", str(shared / "data" / "sequence-learning" / "clean_data_bands.tar.xz"),
                        "-C", tmp], check=True)
        srcs = {"own": _own_session(t), "pub": t / "clean_data" / "user_1" / "session_4"}
        counts: dict[str, int] = {}
        for seed in range(n):
            what, results = fuzz_case(srcs, t / "w", seed)
            bad = problems_of(results)
            print(f"{seed:4} {what:40} {'FAIL ' + '; '.join(bad) if bad else ' '.join(str(c) for _, c, _ in results)}")
            counts["failed" if bad else "ok"] = counts.get("failed" if bad else "ok", 0) + 1
        print(counts)
