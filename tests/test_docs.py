"""The documentation: the site builds with --strict, the generated reference covers every command, flag and key,
and no analysis script lives in docs/ (issue 29)."""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))

import docs_reference  # noqa: E402


def _options(parser: argparse.ArgumentParser) -> list[str]:
    return [o for a in parser._actions if not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS
            for o in a.option_strings]


def test_commands_reference_has_every_command_and_flag():
    from nao_trainer.cli import build_parser

    text = docs_reference.commands_markdown()
    commands = list(docs_reference.walk(build_parser()))
    assert {" ".join(p) for p, _, _ in commands} >= {"run", "mock-robot", "study", "study amend", "study withdraw"}
    for path, parser, _ in commands:
        heading = f"## `nao-trainer {' '.join(path)}`"
        assert heading in text, heading
        section = text.split(heading, 1)[1].split("\n## ", 1)[0]
        for option in _options(parser):
            assert f"`{option}" in section, (path, option)


def test_config_reference_has_every_key_with_its_default():
    import yaml

    from nao_trainer.session.config import SCHEMA

    text = docs_reference.config_markdown()
    defaults = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())

    def keys(schema, prefix):
        for key, rule in schema.items():
            yield from keys(rule, f"{prefix}{key}.") if isinstance(rule, dict) else [f"{prefix}{key}"]

    for dotted in keys(SCHEMA, ""):
        row = next((line for line in text.splitlines() if line.startswith(f"| `{dotted}` |")), None)
        assert row is not None, dotted
        found, value = docs_reference._lookup(defaults, dotted)
        if found:
            assert docs_reference._show(value) in row, (dotted, row)


def test_no_analysis_script_in_docs():
    scripts = [p for p in (ROOT / "docs").rglob("*") if p.suffix in (".py", ".sh")]
    assert scripts == [], f"analysis scripts belong in analysis/, not docs/: {scripts}"


def test_site_builds_strict(tmp_path):
    mkdocs = pytest.importorskip("mkdocs")
    del mkdocs
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_MKDOCS_2_WARNING="1")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir",
                           str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "site" / "reference" / "commands" / "index.html").is_file()
    assert "study amend" in (tmp_path / "site" / "reference" / "commands" / "index.html").read_text()


def test_install_is_quiet(tmp_path):
    """No setuptools warning on build (issue 29: `make demo` printed about 40 about console/static)."""
    import shutil

    for name in ("setup.py", "README.md"):
        shutil.copy(ROOT / name, tmp_path / name)
    shutil.copytree(ROOT / "nao_trainer", tmp_path / "nao_trainer", ignore=shutil.ignore_patterns("__pycache__"))
    done = subprocess.run([sys.executable, "setup.py", "build_py", "-d", str(tmp_path / "out")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "Warning" not in done.stdout + done.stderr, done.stderr[-2000:]
    assert (tmp_path / "out" / "nao_trainer" / "console" / "static" / "console.html").is_file()


FOLDERS = ("tutorials", "how-to", "reference", "explanation")


def test_every_page_lives_in_one_of_the_four_folders():
    """Issue 29: docs/ was 13 flat pages mixing how-to, reference and research. Only the home page stays on top."""
    flat = sorted(p.name for p in (ROOT / "docs").glob("*.md") if p.name != "index.md")
    assert flat == [], f"pages outside {FOLDERS}: {flat}"
    stray = sorted(str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")
                   if p.parent != ROOT / "docs" and p.relative_to(ROOT / "docs").parts[0] not in FOLDERS)
    assert stray == [], stray


DOCS_PAGE = re.compile(r"\bdocs/[\w./-]+?\.md\b")


def _named_pages(text: str) -> set[str]:
    return set(DOCS_PAGE.findall(text))


def test_named_pages_reader_finds_a_page_name():
    assert _named_pages("see docs/explanation/personalisation.md#why, or docs/how-to/study.md.") == {
        "docs/explanation/personalisation.md", "docs/how-to/study.md"}


def test_every_docs_page_named_in_code_config_and_tests_exists():
    """A help text, an error, a config comment or a test that names a page of docs/ names one that exists (the pages
    moved into the folders tutorials, how-to, reference, explanation; MkDocs --strict checks the pages' own links, not the code's)."""
    suffixes = {".py", ".md", ".yaml", ".yml", ".sh", ".txt", ".toml", ".cfg", ".js", ".html", ".css"}
    files = [ROOT / "README.md", ROOT / "Makefile", ROOT / "mkdocs.yml", ROOT / "setup.py"]
    for folder in ("nao_trainer", "tests", "config", "analysis", "benchmarks", "tools", "docs"):
        files += [p for p in (ROOT / folder).rglob("*") if p.suffix in suffixes and "__pycache__" not in p.parts]
    missing = sorted({(str(f.relative_to(ROOT)), page) for f in files if f.is_file()
                      for page in _named_pages(f.read_text(errors="replace")) if not (ROOT / page).is_file()})
    assert missing == [], missing


#: The demo's output as it read before issue 29: a page quoting it teaches words the program no longer prints.
OLD_OUTPUT = re.compile(r"following (?:usp|fixed):\d|posterior: cluster-\d|matched user model: cluster-\d"
                        r"|user models, posterior:|\bL\d\s+(?:enc|chl)\b")


def test_no_page_quotes_the_old_jargon_of_the_output():
    """Issue 29: `-> following usp:3`, `cluster-3` beside `user model 3`, `L2 enc`: the pages quote the output as
    it is now (personalisation.md quoted `matched user model: cluster-3 ...; following fixed:2`)."""
    assert OLD_OUTPUT.search("matched user model: cluster-3 (posterior 0.81; ...); following fixed:2")
    assert not OLD_OUTPUT.search("matched user model 3 (posterior 0.81; ...); policy: fixed level 2")
    quoted = [(str(p.relative_to(ROOT)), m.group(0)) for p in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]
              for m in OLD_OUTPUT.finditer(p.read_text())]
    assert quoted == [], quoted
