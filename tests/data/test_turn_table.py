"""The turn table on its own (``data/turn_table.py``): exact CSV round trip, one-line read errors, the
session filter. Synthetic rows, so it runs without the published data (the importer: test_dataset.py)."""
from __future__ import annotations

import json
import math

import pytest

from nao_trainer.data.turn_table import COLUMNS, SessionFilter, TurnTable, read_table, simulated_sessions, write_table
from nao_trainer.errors import DataError


def rows() -> list[dict]:
    out = []
    for k, (study, kind) in enumerate((("paper", "tactile"), ("paper", "simulated"), ("demo", "simulated"))):
        for turn in (1, 2):
            row = {c: (0.1 + k / 3 if t is float else (0 if t is int else "")) for c, t in COLUMNS.items()}
            row.update(session=f"S{k}", pseudonym=f"P{k}", study=study, input=kind, turn=turn, state=31, length=5,
                       level=2, sequence="ABCAB", response="ABCAB", success=1, score=2, signed_score=2,
                       engagement=float("nan"))
            out.append(row)
    return out


def test_the_csv_round_trip_is_exact_and_keeps_nan(tmp_path):
    table = TurnTable.from_rows(rows())
    path = write_table(table, tmp_path / "t.csv", {"why": "test"})
    back = read_table(path)
    assert back.to_csv() == table.to_csv() and back.fingerprint() == table.fingerprint()
    assert math.isnan(back["engagement"][0]) and back["eeg_quality"][2] == table["eeg_quality"][2]
    assert json.loads((tmp_path / "t.csv.json").read_text()) == {"why": "test"}
    assert back.sessions == ["S0", "S1", "S2"] and len(back) == 6


def test_the_labels_are_not_fingerprinted():
    a, b = rows(), rows()
    for r in b:
        r["study"] = "renamed"
    assert TurnTable.from_rows(a).fingerprint() == TurnTable.from_rows(b).fingerprint()
    b[0]["score"] = 3
    assert TurnTable.from_rows(a).fingerprint() != TurnTable.from_rows(b).fingerprint()


@pytest.mark.parametrize("damage, words", [
    (lambda lines: ["turn,session"] + lines[1:], ":1: not a nao-trainer turn table"),
    (lambda lines: lines[:2] + [lines[2].replace(",31,", ",x31,", 1)], ":3: column 'state' must be int"),
    (lambda lines: lines[:2] + [lines[2].replace(",31,", ",999,", 1)], ":3: state must be in 0..107"),
    (lambda lines: lines[:2] + ["S9,P9"], ":3: expected 23 fields, got 2"),
])
def test_a_damaged_table_names_file_and_line(tmp_path, damage, words):
    path = write_table(TurnTable.from_rows(rows()), tmp_path / "t.csv", {})
    path.write_text("\n".join(damage(path.read_text().splitlines())) + "\n")
    with pytest.raises(DataError) as err:
        read_table(path)
    assert str(err.value).startswith(str(path)) and words in str(err.value) and "\n" not in str(err.value)


def test_the_filter_keeps_studies_and_inputs_and_says_what_it_left_out():
    table = TurnTable.from_rows(rows())
    assert simulated_sessions(table) == ["S1", "S2"]
    kept, dropped = SessionFilter(studies=("paper",), exclude_simulated=True).apply(table)
    assert kept.sessions == ["S0"]
    assert dropped == ["S1: left out by the filter (study 'paper', input 'simulated')",
                       "S2: left out by the filter (study 'demo', input 'simulated')"]
    assert str(SessionFilter()) == "no filter" and SessionFilter(inputs=("tactile",)).apply(table)[0].sessions == ["S0"]
    assert table.mix() == "sessions by study/input: demo/simulated 1, paper/simulated 1, paper/tactile 1"
