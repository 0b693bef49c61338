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


def test_the_summary_says_its_total_leaves_the_invalid_turns_out():
    """`total 41` on the last turn line, `total score: 42` in the summary: the summary says what it left out."""
    from nao_trainer.session.turn import SessionResult

    def row(turn, score, invalid=False):
        return {"turn": turn, "level": 2, "success": score > 0, "score": score, "engagement": None,
                "engagement_note": "EEG off", "invalid": invalid}

    rows = [row(1, 2), row(2, -1, invalid=True), row(3, 2)]
    line = next(ln for ln in SessionResult(Path("x"), "completed", 0, rows, 1).summary().splitlines()
                if ln.startswith("turns completed"))
    assert "total score: 4 (valid turns only: the 1 marked invalid scored -1, left out)" in line
    plain = next(ln for ln in SessionResult(Path("x"), "completed", 0, rows[:1], 1).summary().splitlines()
                 if ln.startswith("turns completed"))
    assert "total score: 2   " in plain and "valid turns only" not in plain


def test_the_policy_choice_is_spelled_out_and_said_to_be_by_expected_value():
    """`following usp:3` / `following fixed:4` were jargon, and `matched user model: cluster-3 ...; following usp:1`
    looked like a contradiction: the lines name the policy in words and say it is chosen by expected value."""
    import numpy as np

    from nao_trainer.core import mdp
    from nao_trainer.policies import personalised
    policy = personalised.load_personalised(None, "g", 25, (), 10.0, 0.5, True, False, guidance=1.0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        policy.guide(mdp.START, 3)  # the supervisor started with level 4: the fixed level-4 candidate is followed
    policy.act(mdp.START, rng)
    status = policy.status()
    assert status["following"] == "fixed:4"
    assert status["progress"].endswith("-> policy: fixed level 4 (by expected value)")
    assert "fixed:" not in status["progress"] and "fixed:" not in status["summary"]
    assert status["summary"].startswith("matched user model ")
    assert ("policy: fixed level 4, chosen by its expected score under the posterior over all the user models "
            "(so not always the matched model's own policy)") in status["summary"]
    assert personalised.plain_name("usp:3", "by expected value") == "personalised (user model 3, by expected value)"


def test_the_posterior_the_match_and_the_policy_name_each_user_model_alike():
    """`run --user-model sim/participants/level2.json` printed `posterior: cluster-3 0.65 | cluster-1 0.25 ...`,
    `matched user model: cluster-3` and `policy: personalised (user model 1)`: two names for one user model. The
    posterior line, the summary and the policy name it `user model N` alike (the files keep `cluster-N`)."""
    import re

    import numpy as np

    from nao_trainer.core import mdp
    from nao_trainer.core.posterior import model_label
    from nao_trainer.policies import personalised
    from nao_trainer.ports import Transition
    policy = personalised.load_personalised(None, "g", 25, (), 10.0, 0.5, False, False)  # no assessment
    rng = np.random.default_rng(0)
    state = mdp.START
    for turn in range(6):
        action = policy.act(state, rng)
        success = turn % 3 != 0
        after = mdp.next_state(state, action, success)
        policy.observe(Transition(state, action, mdp.LENGTHS.index(mdp.decode(after).length) + 1 if success else -1, None, after, False))
        state = after
    status = policy.status()
    assert status["following"]
    shown = status["progress"] + "\n" + status["summary"]
    assert "cluster" not in shown, shown
    named = set(re.findall(r"user model (\d+)", shown))
    assert named == {"1", "2", "3"}, shown
    assert set(status["posterior"]) == {"cluster-1", "cluster-2", "cluster-3"}  # the files keep the names
    best = max(status["posterior"], key=status["posterior"].get)
    assert status["summary"].startswith(f"matched {model_label(best)} (posterior ")
    assert re.search(r"posterior: user model \d \d\.\d\d \| user model \d", status["progress"]), status["progress"]
    assert personalised.plain_name("usp:3").startswith("personalised (user model 3")
    assert model_label("cluster-3") == "user model 3" == personalised.plain_name("usp:3")[len("personalised ("):][:12]
    assert model_label("cluster-2-level-only") == "user model 2 (level-only)"
    assert model_label("span 7.3") == "user model span 7.3"
