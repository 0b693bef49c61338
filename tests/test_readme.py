"""The README has one job (issue 29): short, a legend for every token the demo prints, no results or timings,
and the docs' commands name files that exist and data the way it ships."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
BIN = Path(sys.executable).parent


def _legend() -> str:
    """The first column of the README's legend table (the backticked tokens)."""
    part = README.split("Legend (every token the demo prints):", 1)[1].split("\n## ", 1)[0]
    return " ".join(line.split("|")[1] for line in part.splitlines() if line.startswith("| `"))


def test_readme_is_short_and_has_no_results_or_timings():
    lines = README.splitlines()
    assert len(lines) < 150, len(lines)
    assert max(len(line) for line in lines) < 300  # the old line 60: 1,137 characters of CI figures
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b(?!\s*--consent)", README.replace("--consent-date 2026-12-01", "")), \
        "a date in the README (results and timings belong in the docs)"
    assert not re.search(r"\b\d+ min \d+ s\b|\btests?, \d", README), "test timings belong in the docs"
    for section in ("## Two commands", "## What the demo prints", "## A pilot", "## A real NAO",
                    "## A study in seven commands", "## Documentation"):
        assert section in README, section
    study = README.split("## A study in seven commands", 1)[1].split("\n## ", 1)[0]
    block = study.split("```", 2)[1]
    assert len([line for line in block.splitlines() if line.startswith("nao-trainer ")]) == 7


def _tokens(output: str) -> set[str]:
    """The token classes a session prints: line labels ('label:'), turn-line words, tags and policy names."""
    found: set[str] = set()
    for line in output.splitlines():
        text = line.strip()
        if not text:
            continue
        turn = re.match(r"turn\s+\d+/\d+\s+(L\d)\s+[A-C]+ vs [A-C]*\s+(ok|err)\s+[+-]\d+\s+(total)\s+\d+\s+"
                        r"(E) (-|[\d.]+)(.*)$", text)
        if turn:
            level, verdict, total, e, value, rest = turn.groups()
            found |= {"L1", verdict, total, "turn 3/25", "E -" if value == "-" else "E 0.77"}
            found |= {f"[{tag}]" for tag in re.findall(r"\[(\w+)\]", rest)}
            for note in re.findall(r"\(([^)]*)\)", rest):  # (timeout: ...), (robot feedback: ...), (marked invalid: ...)
                found.add(f"({note.split(':', 1)[0]}:" if ":" in note else f"({note})")
            continue
        if text.startswith("posterior:"):
            found |= {"posterior:", *re.findall(r"user model \d", text), *re.findall(r"cluster-\d", text)}
            policy = re.search(r"-> policy: (\w+)", text)
            if policy:
                found.add(f"-> policy: {policy.group(1)}")
            if "(by expected value)" in text:
                found.add("(by expected value)")
            continue
        if re.match(r"level\s+played\s+success rate", text):
            found.add("level played success rate")
            continue
        if re.match(r"\d+\s+\d+\s+(\d+%|-)$", text):
            continue  # a row of that table
        if text.startswith("connecting to the robot at "):
            found.add("connecting to the robot at")
            continue
        if text.startswith("matched user model ") and "estimated success by level" in text:
            found |= {"matched user model", "estimated success by level", *re.findall(r"cluster-\d", text)}
            continue
        label = re.match(r"([A-Za-z][A-Za-z0-9 %()]*?):", text)
        assert label, f"a line the legend test does not know (teach it, and the README's legend): {text}"
        found.add(label.group(1) + ":" if label.group(1) not in ("EEG (simulated)",) else label.group(1))
        if text.startswith("turns completed:"):
            found |= {"total score", "mean engagement", "EEG in 25 of 25 turns"}
        if text.startswith("matched user model:") and "estimated success by level" in text:
            found.add("estimated success by level")
        if text.startswith("check:"):
            found.add("check: OK" if " OK " in text else "FAIL")
    return found


@pytest.mark.slow
def test_readme_legend_explains_every_token_the_demo_prints(tmp_path):
    """A short seeded demo; each token class it prints is in the README's legend (its first column)."""
    for name in ("config", "sim", "dialogue", "behaviors"):
        (tmp_path / name).symlink_to(ROOT / name)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([str(BIN / "nao-trainer"), "run", "--turns", "7", "--speed", "100", "--seed", "1",
                           "--out", str(tmp_path / "sessions")], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    output = done.stdout + done.stderr
    tokens = _tokens(output)
    assert {"L1", "ok", "total", "[assessment]", "posterior:", "user model 1", "status:"} <= tokens, tokens
    legend = _legend()
    missing = sorted(t for t in tokens if t not in legend and t.rstrip(":") not in legend)
    assert not missing, f"printed by the demo, not in the README's legend: {missing}"


def test_legend_reader_sees_a_token_missing_from_the_legend():
    tokens = _tokens("turn   1/8  L2  ABABC vs ABABC ok  +2  total    2  E 0.50  (robot feedback: encouraging)  (frob: x)  [newtag]\n"
                     "frobnicate: 3\n")
    assert {"(robot feedback:", "(frob:", "[newtag]", "frobnicate:"} <= tokens
    assert "(robot feedback:" in _legend()
    assert not {"(frob:", "[newtag]", "frobnicate:"} & set(_legend().split())


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_docs_name_only_study_files_that_exist():
    """Issue 29: before-first-participant.md and robot.md used config/studies/my-study.yaml, which did not exist."""
    for page in _pages():
        text = page.read_text()
        copied = set(re.findall(r"\bcp\s+\S+\s+(config/\S+\.ya?ml)", text))
        commands = "\n".join(line for line in text.splitlines() if "nao-trainer " in line and "error:" not in line)
        for path in set(re.findall(r"\b(config/(?:studies|protocols)/[\w.-]+\.ya?ml)\b", commands)) - copied:
            assert (ROOT / path).is_file(), f"{page.relative_to(ROOT)} names {path}, which does not ship"


def test_docs_extract_the_data_they_point_study_power_at():
    """Issue 29: study.md's `study power --data ../shared/data/.../clean_data` gave 'no such dataset root': the data
    ships as .tar.xz. Every page that points --data at a path extracts it there first (a tar -x ... -C DIR)."""
    for page in _pages():
        text = page.read_text()
        for data in re.findall(r"study power \S+ .*?--data (\S+)", text):
            if data.isupper() or data.startswith(("ROOT", "DATA", "~")):
                continue  # a placeholder
            targets = re.findall(r"tar -x\w*f \S+\.tar\.xz -C ([\w./~-]+)", text)
            assert any(data.rstrip("/") == f"{t.rstrip('/')}/clean_data" for t in targets), \
                f"{page.relative_to(ROOT)}: study power --data {data}, but the page never extracts the data there"


def test_pilot_says_espeak_is_needed_before_the_desktop_robot():
    """Issue 29: --robot desktop needs espeak-ng and a sound device, said only after it failed."""
    for page in _pages():
        text = page.read_text()
        at = text.find("--robot desktop --input keyboard")
        if at != -1:
            assert "espeak-ng" in text[:at], page.relative_to(ROOT)


def test_readme_says_why_the_bayes_policy_stays_low_and_how_the_choice_is_made():
    assert "--policy bayes" in README and "by expected value" in _legend()
    assert "not always the most likely model's own policy" in README


def test_tutorials_index_links_every_tutorial():
    """Each tutorial page (first-own-task.md too, once it lands) is linked from tutorials/index.md."""
    folder = ROOT / "docs" / "tutorials"
    index = (folder / "index.md").read_text()
    for page in folder.glob("*.md"):
        if page.name != "index.md":
            assert f"]({page.name})" in index, page.name


def test_readme_names_each_user_model_as_the_policy_line_does():
    """Issue 29: the posterior said `cluster-3` where the policy line said `user model 3`: one name for one model."""
    shown = README.split("## What the demo prints", 1)[1].split("```", 2)[1]
    posterior = [line for line in shown.splitlines() if line.strip().startswith("posterior:")]
    assert posterior and all(re.findall(r"user model \d \d\.\d\d", line) for line in posterior), posterior
    assert not re.search(r"cluster-\d", shown), "the demo's output names user models 'user model N'"
    assert "matched user model 3 (posterior" in shown
    assert "`user model 1`" in _legend() and "cluster-" not in _legend()
