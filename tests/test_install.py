"""`make demo` picks a Python the package index serves qi for, or says exactly what to install (issue 27 item 7)."""
from __future__ import annotations

import shutil
import subprocess

import pytest

from nao_trainer.files import PROJECT_ROOT


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_demo_without_a_supported_python_says_what_to_install(tmp_path):
    res = subprocess.run(["make", "-s", "demo", "PYTHON=", f"VENV={tmp_path / 'venv'}"], cwd=PROJECT_ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode != 0
    assert "needs Python 3.10, 3.11 or 3.12" in res.stdout + res.stderr
    assert "sudo apt-get install python3.11 python3.11-venv" in res.stdout + res.stderr
    assert not (tmp_path / "venv").exists()  # nothing half-made


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_picks_an_interpreter_qi_has_wheels_for():
    res = subprocess.run(["make", "-s", "--eval", "print-python: ; @echo $(PYTHON)", "print-python"], cwd=PROJECT_ROOT,
                         capture_output=True, text=True, timeout=60)
    picked = res.stdout.strip()
    if not picked:
        pytest.skip("no Python 3.10-3.12 on this machine")
    version = subprocess.run([picked, "-c", "import sys; print(sys.version_info[:2])"], capture_output=True,
                             text=True, timeout=30).stdout.strip()
    assert version in ("(3, 10)", "(3, 11)", "(3, 12)")
