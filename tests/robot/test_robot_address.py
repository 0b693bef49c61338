"""Issue 17 section 5: a password given in a robot address never reaches the terminal (run and check)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from nao_trainer.files import PROJECT_ROOT

STUDY = str(PROJECT_ROOT / "config" / "default.yaml")
#: (how the address is given, the address, the parts of the password that must not appear)
CASES = [("flag", "tcps://nao:S3c/retPW@127.0.0.1:9503", ("S3c", "retPW")),
         ("flag", "tcps://nao:S3c@retPW@127.0.0.1:9503", ("S3c", "retPW")),
         ("config", "nao:S3cretPW@127.0.0.1", ("S3cretPW",))]


@pytest.mark.parametrize("command", ["run", "check"])
@pytest.mark.parametrize("given, url, secrets", CASES)
def test_a_password_in_the_address_is_refused_without_echoing_it(tmp_path, command, given, url, secrets):
    if given == "flag":
        where = ["--config", STUDY, "--robot", url]
    else:
        study = tmp_path / "study.yaml"
        study.write_text(f'robot:\n  url: "{url}"\n', encoding="utf-8")
        where = ["--config", str(study)]
    res = subprocess.run([sys.executable, "-m", "nao_trainer", command, *where, "--eeg", "off"],
                         capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, QI_LOG_LEVEL="silent"), cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert "NAO_PASSWORD" in res.stderr and "credentials" in res.stderr
    for secret in secrets:
        assert secret not in res.stdout + res.stderr
