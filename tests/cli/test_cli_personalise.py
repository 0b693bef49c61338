"""Personalisation from the command line: `run --policy personalised` live, `evaluate --personalise`."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nao_trainer.cli import main
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.session.record import read_events, read_turns

PARTICIPANTS = PROJECT_ROOT / "sim" / "participants"


STUDY = """study: {name: personalised-test}
robot: {url: mock}
answers: {input: simulated}
policy: {kind: personalised}
"""


def run(out: Path, *args: str) -> subprocess.CompletedProcess:
    """A study whose participants keep their state (policy.state_path null: their folder), unlike the demo."""
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    study = out.parent / "study.yaml"
    study.write_text(STUDY)
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(study), "--out", str(out),
                           "--eeg", "off", "--no-practice", "--speed", "50", "--seed", "2018", "--no-keys", *args],
                          capture_output=True, text=True, env=env, timeout=120)


def session_folders(out: Path, pseudonym: str) -> list[Path]:
    return sorted(p for p in out.iterdir() if p.name.startswith(pseudonym + "_"))


@pytest.mark.slow
def test_weak_and_strong_participants_get_different_levels_and_the_state_carries_over(tmp_path):
    out = tmp_path / "sessions"
    levels = {}
    for who, model in (("weak", "level2.json"), ("strong", "level4.json")):
        res = run(out, "--pseudonym", who, "--user-model", str(PARTICIPANTS / model))
        assert res.returncode == 0, res.stderr
        folder = session_folders(out, who)[0]
        rows = read_turns(folder)
        assert [r["phase"] for r in rows[:6]] == ["assessment"] * 6 and rows[6]["phase"] == "personalised"
        assert [int(r["level"]) for r in rows[:6]] == [2, 2, 3, 3, 4, 4]
        levels[who] = [int(r["level"]) for r in rows[6:]]
        status = [e for e in read_events(folder) if e["event"] == "policy_status"]
        assert len(status) == 25 and abs(sum(status[-1]["posterior"].values()) - 1) < 1e-3
        assert "matched user model " in res.stdout and "posterior" in res.stdout
        assert "posterior: user model " in res.stderr  # the operator sees the posterior move
        # in words (issue 29): which policy, and that it was chosen by expected value, not by the match alone
        assert "-> policy: " in res.stderr and "by expected value)" in res.stderr and "usp:" not in res.stderr
        assert "chosen by its expected score" in res.stdout
        info = json.loads((folder / "session.json").read_text())
        assert info["policy_summary"].startswith("matched user model")
    # clearly different ability, visibly different levels after the assessment
    mean = {who: sum(v) / len(v) for who, v in levels.items()}
    assert mean["weak"] <= 2.3 and mean["strong"] >= 3.0, levels

    again = run(out, "--pseudonym", "weak", "--user-model", str(PARTICIPANTS / "level2.json"), "--turns", "4")
    assert again.returncode == 0, again.stderr
    assert "returns after 1 session(s)" in again.stderr
    rows = read_turns(session_folders(out, "weak")[1])
    assert all(r["phase"] == "personalised" for r in rows)  # no second assessment
    state = json.loads((out / "participants" / "weak" / "personalised.json").read_text())["payload"]
    assert len(state["sessions"]) == 2 and sum(state["played"]) == 29


def test_a_torn_participant_state_is_refused_in_one_line_and_fresh_starts_over(tmp_path):
    out = tmp_path / "sessions"
    path = out / "participants" / "p9" / "personalised.json"
    path.parent.mkdir(parents=True)
    path.write_text('{"format": "nao-trainer/participant-personalisation", "format_')
    res = run(out, "--pseudonym", "p9", "--turns", "2")
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "torn or corrupt" in res.stderr and "--fresh-policy" in res.stderr
    res = run(out, "--pseudonym", "p9", "--turns", "2", "--fresh-policy")
    assert res.returncode == 0, res.stderr
    assert len(list(path.parent.glob("personalised.json.replaced-*"))) == 1 and path.exists()


def test_evaluate_personalise_on_a_held_out_session(dataset_root, own_cache, tmp_path, capsys):
    out, users = tmp_path / "ev", tmp_path / "users"
    rc = main(["evaluate", "--personalise", "--users", "sessions", "--data", str(dataset_root), "--limit", "1",
               "--assessment", "0,3", "--episodes", "300", "--mc-episodes", "30", "--out", str(out), "--no-plots",
               "--json", "--export-users", str(users)])
    assert rc == 0
    said = capsys.readouterr()
    report = json.loads(said.out)
    # issue 29: about 6 minutes on the published data with nothing said; each held-out session is said on stderr
    assert "evaluate --personalise: held-out sessions: 1/1 done" in said.err, said.err
    got = {(s["policy"], s["assessment"]) for s in report["summary"]}
    assert got == {("fixed:2", None), ("best-fixed", None), ("generic", None), ("oracle", None),
                   *((p, a) for p in ("paper", "posterior-ev", "personalised") for a in (0, 3))}
    oracle = next(s for s in report["summary"] if s["policy"] == "oracle")
    exact = [s for s in report["summary"] if s["assessment"] is None]
    assert all(oracle["score"] >= s["score"] - 1e-9 for s in exact)
    assert [e["turns"] for e in report["engagement_information"]] == [6, 12, 25]
    assert all(e["people"] == 1 and e["sessions"] == 1 for e in report["engagement_information"])
    # the per-session measurements are stored: the table is re-summarised (over people) without a rerun
    from nao_trainer.experiments import personalisation, reports

    meas = reports.read_engagement_rows(out / report["engagement_rows_file"])
    assert [m["turns"] for m in meas] == [6, 12, 25] and len({m["user"] for m in meas}) == 1
    assert meas[0]["user"].startswith("session:user_")
    assert personalisation.summarise_engagement(meas) == report["engagement_information"]
    # the engagement part alone (analysis/engagement_information.py, no policy trained) writes what the full run wrote
    stored = (out / "engagement_rows.csv").read_bytes()
    spec = importlib.util.spec_from_file_location("engagement_information",
                                                  PROJECT_ROOT / "analysis" / "engagement_information.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    again = script.rewrite(dataset_root, [out], limit=1)[out]
    assert (out / "engagement_rows.csv").read_bytes() == stored
    assert again["engagement_information"] == report["engagement_information"]
    assert again["summary"] == report["summary"] and again["engagement_command"].endswith(str(out))
    beside = {s["policy"]: s for s in report["ceiling"]["summary"]}  # the Bayes ceiling section (issue 21)
    assert {"ceiling", "bayes", "bayes-psychometric", "questplus", "staircase-2d1u@2", "oracle-objective"} <= set(beside)
    assert beside["oracle-objective"]["value"] >= beside["ceiling"]["value"] - 1e-9
    assert (out / "personalise.csv").read_text().startswith("policy,assessment,users,people,score")
    import gzip

    with gzip.open(out / "personalise_rows.csv.gz", "rt") as fh:
        lines = fh.read().splitlines()
    assert lines[0].startswith("user,cluster,user_best_level,policy,assessment") and len(lines) == 1 + 4 + 3 * 2
    from nao_trainer.learn.artifacts import load_simulator_file

    (exported,) = list(users.iterdir())
    assert load_simulator_file(exported).name.startswith("session:")


@pytest.mark.slow
def test_the_engagement_measurements_do_not_depend_on_the_session_prior(dataset_root, own_cache):
    """What lets analysis/engagement_information.py recompute the own-rates outputs' engagement part with the
    default session prior: the held-out fits it uses are the same for every --session-prior."""
    from nao_trainer.experiments import personalisation
    from nao_trainer.learn.artifacts import load_manifest
    from nao_trainer.learn.fitting import Turns
    from nao_trainer.learn.users import read_turns

    turns = Turns.from_columns(read_turns(dataset_root, load_manifest(None)["compat"]).columns)
    data, own = (personalisation.held_out(turns, "user_1/session_4", 3, 50, 0, prior) for prior in (None, 2.0))
    assert not (data.user.truth.p_success == own.user.truth.p_success).all()  # the users differ ...
    assert personalisation.engagement_information(own) == personalisation.engagement_information(data)  # not this


@pytest.mark.parametrize("args", [["--users", "clusters"], ["--users", "sessions"],
                                  ["--users", "sessions", "--data", ".", "--assessment", "0-30"]])
def test_evaluate_personalise_bad_input_is_one_line(args, tmp_path, capsys):
    assert main(["evaluate", "--personalise", *args, "--out", str(tmp_path / "e"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err
