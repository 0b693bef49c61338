"""Long commands say their progress on stderr (issue 29: `evaluate --personalise` ran ~6 minutes silently)."""
from __future__ import annotations

import math

import pytest

from nao_trainer.learn.parallel import fan_out


@pytest.mark.parametrize("workers", [1, 2])
def test_fan_out_says_each_finished_task_on_stderr(capsys, workers):
    assert fan_out(math.pow, [(2, 1), (2, 2), (2, 3)], workers, progress="sweep: runs") == [2.0, 4.0, 8.0]
    lines = capsys.readouterr().err.strip().splitlines()
    assert [ln.split(",")[0] for ln in lines] == ["sweep: runs: 1/3 done", "sweep: runs: 2/3 done",
                                                  "sweep: runs: 3/3 done"]
    assert "left" in lines[0] and "left" not in lines[-1]
    fan_out(math.pow, [(2, 1)], workers)
    assert capsys.readouterr().err == ""  # no label: nothing said
