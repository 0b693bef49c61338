"""Seeded fuzzing of study files: every broken file is refused in one line naming file and line, exit code 2.

Each mutation of ``config/default.yaml`` is bad by construction (NaN, infinity, a 400-digit number,
a wrong type, a tag that cannot convert, a control character, a repeated key, NUL or a lone
surrogate in a path, an unknown key, an empty file...). Each file goes through ``nao-trainer run``
as a user would start it, pointed at a closed port: a file that wrongly passes ends with exit
code 3 (robot unreachable) and counts as a failure, like a traceback. ``python
tests/test_config_fuzz.py 1000`` runs a larger batch and prints the counts.
"""
from __future__ import annotations

import contextlib
import io
import re
import sys
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
BASE = ROOT / "config" / "default.yaml"
N_SUITE = 150

NON_FINITE = (".nan", ".NaN", ".inf", "-.inf", "!!float nan", "!!float inf")
HUGE = "9" * 400
BAD_TAGS = ("!!int notanumber", "!!float abc", "!!timestamp 2020-13-45", "!!bool maybe", "!!int 0x")
CONTROL = [chr(c) for c in (*range(0x00, 0x09), 0x0B, 0x0C, *range(0x0E, 0x20), 0x7F)]
PATH_KEYS = ("session.dialogue", "session.behaviors", "session.output", "policy.state_path")
PATH_POISON = ('"dialogue/\\0en.yaml"', '"\\ud800"', '"sessions\\udfff/x"', '"\\0"')
PROCESSING_KEYS = ("window_s", "hop_s", "ewma_a", "resolve_timeout_s", "loss_timeout_s", "min_quality",
                   "min_clean_channels", "gap_tolerance_s", "end_wait_s", "poll_s")


def _leaves(text: str) -> dict[str, tuple[int, object]]:
    """Dotted key -> (line index, default value) of every leaf setting of the base file."""
    from nao_trainer.files import read_yaml

    data, lines, _ = read_yaml(BASE)
    out = {}
    for key, line in lines.items():
        value = data
        for part in key.split("."):
            value = value[part]
        if not isinstance(value, dict) or not value:
            out[key] = (line - 1, value)
    return out


def _set_line(text: str, index: int, key: str, value: str) -> str:
    lines = text.splitlines()
    indent = re.match(r"\s*", lines[index]).group(0)
    lines[index] = f"{indent}{key.rsplit('.', 1)[-1]}: {value}"
    return "\n".join(lines) + "\n"


def mutate(text: str, rng: np.random.Generator) -> tuple[str, str]:
    """A bad variant of ``text`` and what was done to it."""
    leaves = _leaves(text)
    keys = sorted(leaves)
    numeric = [k for k in keys if isinstance(leaves[k][1], (int, float)) and not isinstance(leaves[k][1], bool)]
    kind = str(rng.choice(["non_finite", "huge", "wrong_type", "bad_tag", "control", "dup_section", "dup_key",
                           "path_poison", "empty", "unknown_key", "negative", "processing", "list_nan",
                           "section_type"]))
    pick = lambda seq: seq[int(rng.integers(len(seq)))]  # noqa: E731
    if kind in ("non_finite", "huge", "negative"):
        key = pick(numeric)
        value = {"non_finite": pick(NON_FINITE), "huge": pick([HUGE, "-" + HUGE, HUGE + ".5", "1e400"]),
                 "negative": pick(["-7.5", "-1", "-1e300"])}[kind]
        if kind == "huge" and value == "1e400":
            value = "1.0e+400"  # YAML 1.1 needs the dot and sign to read a float: inf
        return _set_line(text, leaves[key][0], key, value), f"{key}: {value}"
    if kind == "wrong_type":
        key = pick(keys)
        default = leaves[key][1]
        value = ('"five"' if isinstance(default, (bool, int, float, list)) else "[1, 2]")
        return _set_line(text, leaves[key][0], key, value), f"{key}: {value}"
    if kind == "bad_tag":
        key, value = pick(keys), pick(BAD_TAGS)
        return _set_line(text, leaves[key][0], key, value), f"{key}: {value}"
    if kind == "control":
        pos = int(rng.integers(len(text)))
        char = pick(CONTROL)
        return text[:pos] + char + text[pos:], f"U+{ord(char):04X} at offset {pos}"
    if kind == "dup_section":
        sections = re.findall(r"(?m)^([a-z_]+):", text)
        section = pick(sections)
        return text + f"{section}: {{}}\n", f"second {section}:"
    if kind == "dup_key":
        key = pick(keys)
        index = leaves[key][0]
        lines = text.splitlines()
        lines.insert(index + 1, lines[index])
        return "\n".join(lines) + "\n", f"{key} twice"
    if kind == "path_poison":
        key, value = pick(PATH_KEYS), pick(PATH_POISON)
        return _set_line(text, leaves[key][0], key, value), f"{key}: {value}"
    if kind == "empty":
        return pick(["", "\n", "# only a comment\n", "---\n", "~\n"]), "empty"
    if kind == "unknown_key":
        key = pick(keys)
        index = leaves[key][0]
        lines = text.splitlines()
        indent = re.match(r"\s*", lines[index]).group(0)
        lines.insert(index + 1, f"{indent}{key.rsplit('.', 1)[-1]}_typo: 1")
        return "\n".join(lines) + "\n", f"{key}_typo"
    if kind == "processing":
        name = pick(PROCESSING_KEYS)
        value = pick([*NON_FINITE, HUGE, '"x"', "-1", "[1]"])
        key = "eeg.processing"
        return _set_line(text, leaves[key][0], key, f"{{{name}: {value}}}"), f"eeg.processing.{name}: {value}"
    if kind == "list_nan":
        key = pick(["participant_model.success_by_level", "participant_model.engagement_by_level"])
        value = pick(["[.nan, 0.5, 0.5, 0.5]", "[0.5, .inf, 0.5, 0.5]", f"[0.5, 0.5, {HUGE}, 0.5]"])
        return _set_line(text, leaves[key][0], key, value), f"{key}: {value}"
    section = pick(sorted({k.split(".")[0] for k in keys}))
    if rng.random() < 0.5:
        return "- a list\n- not a mapping\n", "a list, not a mapping"
    return re.sub(rf"(?m)^{section}:.*$", f"{section}: 5", text, count=1), f"{section}: 5"


def outcome(path: Path, out: Path) -> tuple[str, int, str]:
    """("ok"|"traceback"|"exit N"|"lines N", exit code, stderr) of `nao-trainer run` on ``path``."""
    from nao_trainer.cli import main

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["run", "--config", str(path), "--robot", "tcp://127.0.0.1:1", "--turns", "1",
                         "--out", str(out), "--quiet", "--pseudonym", "P1"])
    except BaseException:  # noqa: BLE001 - what the fuzz looks for
        return "traceback", -1, traceback.format_exc()
    text = err.getvalue().strip()
    if code != 2:
        return f"exit {code}", code, text
    if len(text.splitlines()) != 1:
        return f"lines {len(text.splitlines())}", code, text
    if not re.search(rf"{re.escape(path.name)}(:\d+)?\b", text):
        return "no file named", code, text
    return "ok", code, text


def run_batch(n: int, folder: Path, seed: int = 2026) -> dict[str, list[tuple[str, str]]]:
    base = BASE.read_text(encoding="utf-8")
    rng = np.random.default_rng(seed)
    results: dict[str, list[tuple[str, str]]] = {}
    for i in range(n):
        text, what = mutate(base, rng)
        path = folder / f"study_{i:04d}.yaml"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        status, _, message = outcome(path, folder / "out")
        results.setdefault(status, []).append((what, message.splitlines()[-1] if message else ""))
    return results


def test_mutated_study_files_are_all_refused_in_one_line_with_exit_2(tmp_path):
    results = run_batch(N_SUITE, tmp_path)
    bad = {status: cases[:5] for status, cases in results.items() if status != "ok"}
    assert not bad, bad
    assert len(results["ok"]) == N_SUITE


if __name__ == "__main__":  # python tests/test_config_fuzz.py 1000
    import tempfile

    sys.path.insert(0, str(ROOT))
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    with tempfile.TemporaryDirectory() as tmp:
        results = run_batch(n, Path(tmp))
    for status, cases in sorted(results.items()):
        print(f"{status:>12}: {len(cases)}")
        if status != "ok":
            for what, message in cases[:8]:
                print(f"    {what!r:50.50} -> {message[:150]}")
