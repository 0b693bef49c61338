"""A withdrawal is refused while the participant's session runs (deleting its folder under it)."""
from __future__ import annotations

import json
import socket
import subprocess
import sys

from _study_data import registry_state, write_protocol
from nao_trainer.cli import main


def test_withdrawal_waits_for_the_running_session_and_is_recorded_after(tmp_path, capsys):
    root = tmp_path / "study"
    assert main(["study", "init", str(write_protocol(tmp_path)), "--out", str(root)]) == 0
    assert main(["study", "enrol", str(root), "--consent-date", "2026-11-02", "--consent-version", "v1"]) == 0
    (root / "locks").mkdir()
    (root / "sessions" / "P001_20261102-100000").mkdir()
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    lock = root / "locks" / "P001.lock"
    try:
        lock.write_text(json.dumps({"pid": sleeper.pid, "host": socket.gethostname(), "started": "now"}))
        capsys.readouterr()
        registry = registry_state(root)
        code = main(["study", "withdraw", str(root), "P001", "--data", "delete"])
        err = capsys.readouterr().err
        assert code == 2 and "a session is running" in err and len(err.strip().splitlines()) == 1, err
        assert registry_state(root) == registry
        assert (root / "sessions" / "P001_20261102-100000").exists()
    finally:
        sleeper.kill()
        sleeper.wait()
    assert main(["study", "withdraw", str(root), "P001", "--data", "keep"]) == 0  # its process is gone: stale
    assert "withdrawal recorded" in capsys.readouterr().out
