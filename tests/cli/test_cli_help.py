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
