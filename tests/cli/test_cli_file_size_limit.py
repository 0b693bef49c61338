"""A full disk under train and evaluate, made with a file size limit in a child process (RLIMIT_FSIZE in
preexec_fn; Python ignores SIGXFSZ, so a write past it fails with EFBIG as a full disk fails with ENOSPC):
one line naming the file or folder, the cause and the fix, exit 2, no traceback (issue 30)."""
from __future__ import annotations

import errno
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from nao_trainer.files import cannot_write

HANG = 300  # a hang limit for the child, not a timing bound


def nao_trainer(tmp_path: Path, limit: int, *args: str) -> subprocess.CompletedProcess:
    def limit_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = dict(os.environ, QI_LOG_LEVEL="silent", XDG_CACHE_HOME=str(tmp_path / "cache"),
               MPLCONFIGDIR=str(tmp_path / "mpl"))
    return subprocess.run([sys.executable, "-m", "nao_trainer", *args], capture_output=True, text=True, env=env,
                          stdin=subprocess.DEVNULL, timeout=HANG, preexec_fn=limit_files)


def one_line_error(done: subprocess.CompletedProcess, command: str) -> str:
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"nao-trainer {command}: error: "), done.stderr
    return last


def test_evaluate_outputs_past_the_limit_are_one_line(tmp_path):
    """evaluation.json past the limit was a traceback (OSError: [Errno 27] File too large)."""
    out = tmp_path / "e"
    done = nao_trainer(tmp_path, 1024, "evaluate", "--users", "level-only", "--policies", "fixed:2,best-fixed",
                       "--mc-episodes", "20", "--workers", "1", "--no-plots", "--no-ceiling", "--out", str(out))
    last = one_line_error(done, "evaluate")
    assert f"{out / 'evaluation.json'}: cannot write (the file is larger than this system allows); raise the file " \
        "size limit (ulimit -f)" in last, last


def test_train_outputs_past_the_limit_say_the_cause_and_its_fix(tmp_path):
    """train said "(File too large); choose a writable --out": a fix that does not fix a full disk."""
    out = tmp_path / "t"
    done = nao_trainer(tmp_path, 2048, "train", "--seeds", "1", "--episodes", "50", "--methods", "performance",
                       "--workers", "1", "--no-plots", "--out", str(out))
    last = one_line_error(done, "train")
    assert "cannot write outputs (the file is larger than this system allows); raise the file size limit " \
        "(ulimit -f), or choose a writable --out" in last, last


@pytest.mark.parametrize("code, words", [
    (errno.ENOSPC, "(the disk is full); free some space on it, or choose another --out"),
    (errno.EFBIG, "(the file is larger than this system allows); raise the file size limit (ulimit -f), or choose "
                   "another --out"),
    (errno.ENOTDIR, "(Not a directory); choose another --out"),
])
def test_cannot_write_names_the_file_the_cause_and_the_fix(code, words):
    named = OSError(code, os.strerror(code), "/x/models/cluster_1.json")
    assert cannot_write("/x/models", "the user models", named, "choose another --out") \
        == f"/x/models/cluster_1.json: cannot write the user models {words}"
    unnamed = OSError(code, os.strerror(code))  # a failed write() names no file: the folder is named
    assert cannot_write("/x/models", "", unnamed, "choose another --out").startswith("/x/models: cannot write (")
