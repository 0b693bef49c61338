"""The command line's help and its mistakes (issue 29): every command listed, a command's own usage on a bad flag."""
from __future__ import annotations

import pytest

from nao_trainer.cli import COMMANDS, main
from nao_trainer.cli.study import ACTIONS


def test_top_level_help_lists_every_command_and_study_action(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name.replace("_data", "").replace("_", "-") in out, name
    study_line = " ".join(out.split("study", 2)[-1].split())  # the study entry, wrapped lines joined
    for action in ACTIONS:
        if action != "table":
            assert action in study_line, action


def test_a_mistyped_flag_prints_the_commands_usage(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--polcy", "bayes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: nao-trainer run ") and "unrecognized arguments: --polcy bayes" in err


def test_a_reader_that_goes_away_ends_quietly(tmp_path):
    """`nao-trainer ... | head`: the pipe closes before the output is written; no traceback, exit 0 (the
    BrokenPipeError handler sat after the OSError one, which re-raised it)."""
    import os
    import subprocess
    import sys

    r, w = os.pipe()
    os.close(r)  # the reader is gone before the command writes anything
    try:
        done = subprocess.run([sys.executable, "-m", "nao_trainer", "plugins"], stdout=w, stderr=subprocess.PIPE,
                              text=True, timeout=120, env=dict(os.environ, QI_LOG_LEVEL="silent"))
    finally:
        os.close(w)
    assert "Traceback" not in done.stderr and done.returncode == 0, done.stderr
