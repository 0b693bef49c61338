"""A newcomer's first hour on the command line (issue 29, "What we found"): each stumble has a test here."""
from __future__ import annotations

import io
import os
from pathlib import Path

import pytest

from nao_trainer.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _setup_packages() -> set[str]:
    """The package list setup.py hands setuptools (run up to its configuration, nothing built)."""
    import setuptools  # noqa: F401  (first: distutils is then setuptools' own)
    from distutils.core import run_setup as run
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)
        dist = run(str(ROOT / "setup.py"), stop_after="init")
    finally:
        os.chdir(cwd)
    return set(dist.packages)


def test_every_shipped_folder_is_a_package_so_install_is_quiet():
    """setuptools warns (BuildBackendWarning, ~40 on `make demo`) for each data folder that is not in `packages`."""
    packages = _setup_packages()
    for folder in (ROOT / "nao_trainer").rglob("*"):
        if folder.is_dir() and folder.name != "__pycache__" and any(f.is_file() for f in folder.iterdir()):
            dotted = ".".join(folder.relative_to(ROOT).parts)
            assert dotted in packages, f"{dotted} ships files but is absent from setup.py's packages"
    assert "nao_trainer.console.static" in packages


def test_run_help_says_what_the_desktop_robot_needs(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    desktop = text[text.index("'desktop'"):][:300]
    assert "espeak-ng" in desktop and "sound device" in desktop and "WAV" in desktop


def test_desktop_robot_says_at_start_that_there_is_no_sound_device(monkeypatch):
    from nao_trainer.session.robot_setup import desktop_robot
    monkeypatch.setenv("NAO_TRAINER_AUDIO", "files")
    progress = io.StringIO()
    robot = desktop_robot("keyboard", 1.0, progress)
    try:
        assert "espeak-ng" in progress.getvalue() and "no sound device" in progress.getvalue()
    finally:
        robot.close()
