"""A small sample of issue 30's stress test: each study command SIGKILLed at a random moment and run
once under a file-size limit; the study stays whole (tests/_study_kills.py says what that means).
The full run (50 kills and 20 disk fills per command): benchmarks/bench_study_kills.py."""
from __future__ import annotations

import io

import pytest

from _study_kills import run


@pytest.mark.slow
def test_kills_and_full_disks_leave_every_study_whole(tmp_path):
    out = io.StringIO()
    results = run(tmp_path, kills=1, fills=1, seed=20261202, out=out)
    failures = [f for killed, filled in results.values() for f in killed.failures + filled.failures]
    assert not failures, out.getvalue()
    assert all(k.trials == 1 and f.trials == 1 for k, f in results.values())
