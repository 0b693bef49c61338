"""The live Bayes policy with the pooled psychometric prior (``policy.prior``, issue 21).

Sessions run in this process through the real command line (``cli.main``: mock robot = the NAO
stand-in over qi, simulated participant, EEG off), so the planner compiles once; horizons are short.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.core import bayes, objective
from nao_trainer.errors import DataError
from nao_trainer.files import PROJECT_ROOT

pytestmark = pytest.mark.skipif(not bayes.available(), reason="the planner needs numba")
LEVEL4 = PROJECT_ROOT / "sim" / "participants" / "level4.json"


def run(tmp: Path, capsys, *args: str) -> tuple[int, str, str]:
    from nao_trainer.cli import main

    study = tmp / "study.yaml"
    study.write_text("study: {name: bayes-prior}\npolicy: {kind: bayes, objective: 'target:0.75'}\n")
    code = main(["run", "--config", str(study), "--robot", "mock", "--input", "simulated", "--eeg", "off",
                 "--policy", "bayes", "--turns", "4", "--speed", "200", "--no-practice", "--seed", "7", "--no-keys",
                 "--quiet", "--out", str(tmp / "sessions"), "--user-model", str(LEVEL4), *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_psychometric_prior_live_over_two_sessions_refused_with_another_prior_or_participant(
        tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    # target:0.75 without policy.prior: the psychometric prior (the default under a target rate)
    code, out, err = run(tmp_path, capsys, "--pseudonym", "p1")
    assert code == 0, err
    assert "Bayes planner (target-p:0.75, prior psychometric)" in out
    state = tmp_path / "sessions" / "participants" / "p1" / "bayes.json"
    saved = json.loads(state.read_text())["payload"]
    assert saved["pseudonym"] == "p1" and saved["prior"] == "psychometric" and sum(saved["counts"]) == 4
    assert saved["models"][0].startswith("span ") and len(saved["models"]) > 20  # the grid of spans
    code, out, err = run(tmp_path, capsys, "--pseudonym", "p1", "--prior", "psychometric")  # said explicitly: same
    assert code == 0, err
    again = json.loads(state.read_text())["payload"]
    assert sum(again["counts"]) == 8 and len(again["sessions"]) == 2
    assert again["counts"][:] == [a + b for a, b in zip(saved["counts"], again["sessions"][1]["counts"])]
    # the clusters as prior: another fingerprint, refused in one line, exit 2, the file untouched
    code, out, err = run(tmp_path, capsys, "--pseudonym", "p1", "--prior", "clusters")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "another prior or objective (psychometric, target-p:0.75," in err
    assert json.loads(state.read_text())["payload"]["counts"] == again["counts"]
    # p1's file copied into p2's folder: refused in one line, exit 2
    foreign = tmp_path / "sessions" / "participants" / "p2" / "bayes.json"
    foreign.parent.mkdir(parents=True)
    shutil.copy(state, foreign)
    code, out, err = run(tmp_path, capsys, "--pseudonym", "p2")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{foreign}: the participant state of 'p1', not of 'p2'" in err


@pytest.mark.parametrize("name", ["target:0.75", "target-rate:0.75"])
def test_live_table_is_the_evaluations_bayes_psychometric_for_the_same_prior(tmp_path, name):
    """The evaluation builds its prior as ``PooledModel(**fit).mixture()`` (cli.ceiling_report) and
    solves it in ``experiments.ceiling.prior_rows``; the live policy from the shipped file must give
    the same table, first decision and expected turns per level."""
    from nao_trainer.core.psychometric import PooledModel
    from nao_trainer.experiments import ceiling
    from nao_trainer.learn.bayes_cache import solve_cached
    from nao_trainer.learn.psychometric_prior import load_prior
    from nao_trainer.policies.bayes import load_bayes

    turns, obj = 10, objective.parse(name)
    live = load_bayes(None, "p1", turns, str(obj), False, "psychometric", cache=tmp_path / "live")
    fit = dict(load_prior().__dict__)  # what personalisation stores as fits[user]["psychometric"]
    pk, wk = PooledModel(**fit).mixture()
    plan = solve_cached(pk, wk, obj.coefficients(4), turns, 0, tmp_path / "evaluation",
                        terminal=obj.terminal(turns))  # solved anew
    assert (plan.terminal is not None) == obj.per_session
    assert np.array_equal(live.plan.action, plan.action) and live.plan.value == pytest.approx(plan.value, abs=1e-12)
    assert live.decide() == plan.decide(np.zeros(8, dtype=np.int64))
    user = np.array([0.99, 0.9, 0.6, 0.2])
    row = ceiling.prior_rows({"u": (pk, wk)}, {"u": user}, {}, obj, turns, tmp_path / "evaluation",
                             "bayes-psychometric")[0]
    mine = bayes.evaluate_plan(live.plan, user[None])
    assert np.allclose(row["visits"], np.round(mine.visits[0], 4)) and row["utility"] == pytest.approx(
        float(mine.session[0]), abs=1e-9)


def test_read_state_refuses_another_participants_file(tmp_path):
    from nao_trainer.policies.bayes import BayesPolicy, read_state

    p = np.array([[0.99, 0.95, 0.2, 0.05], [0.99, 0.95, 0.9, 0.85]])
    pol = BayesPolicy(("weak", "strong"), p, np.ones(2), objective.SCORE, 3, tmp_path / "P01" / "bayes.json",
                      cache=tmp_path, pseudonym="P01", prior="test")
    pol.save()
    assert read_state(pol.path, pol.fingerprint, "P01")["pseudonym"] == "P01"
    copied = tmp_path / "P02" / "bayes.json"
    copied.parent.mkdir()
    shutil.copy(pol.path, copied)
    with pytest.raises(DataError) as err:
        read_state(copied, pol.fingerprint, "P02")
    msg = str(err.value)
    assert msg.startswith(f"{copied}: the participant state of 'P01', not of 'P02'") and "\n" not in msg
    assert "--fresh-policy" in msg


@pytest.mark.parametrize("prior, first", [("clusters", "cluster"), ("psychometric", "span ")])
def test_named_priors_and_a_folder_of_users(tmp_path, prior, first):
    from nao_trainer.errors import ConfigError
    from nao_trainer.policies.bayes import default_prior, model_prior

    names, p, w = model_prior(prior)
    assert names[0].startswith(first) and p.shape == (len(names), 4) and np.all(w > 0)
    assert default_prior(objective.SCORE) == "clusters" and default_prior(objective.parse("target:0.8")) == "psychometric"
    folder = tmp_path / "users"
    folder.mkdir()
    shutil.copy(LEVEL4, folder / "a.json")
    names, p, w = model_prior(str(folder))
    assert len(names) == 1 and w.tolist() == [1.0]
    with pytest.raises(ConfigError, match="no user simulator files"):
        model_prior(str(tmp_path))


def test_a_folder_prior_with_a_simulator_of_another_definition_is_one_line(tmp_path):
    """Issue 30, finding 5: a DefinitionMismatch (a ValueError of core) escaped as a traceback."""
    from nao_trainer.policies.bayes import model_prior

    folder = tmp_path / "users"
    folder.mkdir()
    data = json.loads(LEVEL4.read_text())
    data["mdp_definition"] = "another definition"
    (folder / "a.json").write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        model_prior(str(folder))
    msg = str(err.value)
    assert msg.startswith(f"{folder / 'a.json'}: made for another state/action definition") and "\n" not in msg
    assert "nao-trainer fit" in msg


@pytest.mark.parametrize("turns", [500, 60])
def test_a_horizon_whose_plan_would_not_fit_in_memory_is_refused_before_solving(tmp_path, turns, monkeypatch):
    """Issue 30, finding 5: --turns 500 tried to allocate 91 PiB (ArrayMemoryError), 60 turns 46 GiB."""
    from nao_trainer.errors import ConfigError
    from nao_trainer.learn import bayes_cache
    from nao_trainer.policies.bayes import load_bayes

    monkeypatch.setattr(bayes_cache, "memory_limit", lambda: 8 * 2**30)  # whatever this machine has free now
    with pytest.raises(ConfigError) as err:
        load_bayes(None, "P01", turns, "score", False, "clusters", cache=tmp_path)
    msg = str(err.value)
    assert f"a plan of {turns} turns at 4 levels needs" in msg and "more than the 8.0 GiB available" in msg
    assert "play at most 45 turns (--turns or session.turns)" in msg and "\n" not in msg
    assert not list(tmp_path.iterdir())  # nothing read, solved or written
