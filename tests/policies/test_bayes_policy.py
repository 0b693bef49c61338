"""The live Bayes policy through real sessions (mock robot, simulated participant, fast speed):
one session, two sessions with the counts carried over, and a foreign or torn state refused."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.core import bayes, mdp
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.ports import Transition
from nao_trainer.session.record import read_turns

pytestmark = pytest.mark.skipif(not bayes.available(), reason="the planner needs numba")
PARTICIPANTS = PROJECT_ROOT / "sim" / "participants"


def study(tmp: Path, objective: str = "score") -> Path:
    path = tmp / f"study-{objective.replace(':', '_')}.yaml"
    path.write_text("study: {name: bayes-test}\nrobot: {url: mock}\nanswers: {input: simulated}\n"
                    f"policy: {{kind: bayes, objective: '{objective}'}}\n")
    return path


def run(tmp: Path, out: Path, *args: str, objective: str = "score") -> subprocess.CompletedProcess:
    env = dict(os.environ, QI_LOG_LEVEL="silent", XDG_CACHE_HOME=str(tmp / "cache"))
    return subprocess.run([sys.executable, "-m", "nao_trainer", "run", "--config", str(study(tmp, objective)),
                           "--out", str(out), "--eeg", "off", "--no-practice", "--speed", "200", "--seed", "7",
                           "--no-keys", "--pseudonym", "p1", "--user-model", str(PARTICIPANTS / "level4.json"), *args],
                          capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow
def test_bayes_live_over_two_sessions_keeps_the_counts_and_refuses_foreign_or_torn_state(tmp_path):
    out = tmp_path / "sessions"
    first = run(tmp_path, out)
    assert first.returncode == 0, first.stderr
    state = out / "participants" / "p1" / "bayes.json"
    saved = json.loads(state.read_text())["payload"]
    folders = sorted(p for p in out.iterdir() if p.name.startswith("p1_"))
    rows = read_turns(folders[0])
    assert len(rows) == 25 and sum(saved["counts"]) == 25
    # the counts on disk are the session's turns, level by level
    for lv in (1, 2, 3, 4):
        mine = [r for r in rows if int(r["level"]) == lv]
        wins = sum(1 for r in mine if int(r["score"]) > 0)
        assert saved["counts"][2 * lv - 2: 2 * lv] == [wins, len(mine) - wins]
    assert "Bayes planner (score, prior clusters)" in first.stdout  # score: the clusters by default
    second = run(tmp_path, out)
    assert second.returncode == 0, second.stderr
    assert "returns after 1 session(s)" in second.stderr
    saved2 = json.loads(state.read_text())["payload"]
    assert sum(saved2["counts"]) == 50 and len(saved2["sessions"]) == 2
    # another objective: another prior fingerprint, refused in one line, exit 2
    foreign = run(tmp_path, out, objective="target:0.75")
    assert foreign.returncode == 2
    assert "another prior or objective" in foreign.stderr and "Traceback" not in foreign.stderr
    assert len(foreign.stderr.strip().splitlines()) == 1
    # a torn file: refused; --fresh-policy keeps it aside and starts from the prior
    state.write_text(state.read_text()[:100])
    torn = run(tmp_path, out)
    assert torn.returncode == 2 and "torn or corrupt" in torn.stderr
    fresh = run(tmp_path, out, "--fresh-policy")
    assert fresh.returncode == 0, fresh.stderr
    assert list(state.parent.glob("bayes.json.replaced-*"))
    assert sum(json.loads(state.read_text())["payload"]["counts"]) == 25


def test_policy_follows_its_plan_and_counts_overrides(tmp_path):
    from nao_trainer.core import objective
    from nao_trainer.policies.bayes import BayesPolicy

    p = np.array([[0.99, 0.95, 0.2, 0.05], [0.99, 0.95, 0.9, 0.85]])
    pol = BayesPolicy(("weak", "strong"), p, np.array([1.0, 1.0]), objective.SCORE, 10, tmp_path / "b.json",
                      cache=tmp_path)
    rng = np.random.default_rng(0)
    plan = bayes.solve(p, [0.5, 0.5], objective.SCORE.coefficients(), 10)
    counts = np.zeros(8, dtype=np.int64)
    state = mdp.START
    for t in range(10):
        a = pol.act(state, rng)
        assert a + 1 == plan.decide(counts)
        played = 1 if t == 3 else a  # turn 3: a supervisor's override to level 2
        nxt = played * 27 + 4  # (level, no feedback, previous result 0): index of core.mdp
        success = t % 3 != 0
        pol.observe(Transition(state, played, (played + 1) if success else -1, None, nxt, t == 9))
        counts[2 * played + (0 if success else 1)] += 1
        state = nxt
    assert pol.counts.tolist() == counts.tolist()
    assert json.loads((tmp_path / "b.json").read_text())["payload"]["counts"] == counts.tolist()


def test_restore_from_a_checkpoint_does_not_count_the_session_twice(tmp_path):
    from nao_trainer.core import objective
    from nao_trainer.policies.bayes import BayesPolicy

    p = np.array([[0.99, 0.95, 0.2, 0.05], [0.99, 0.95, 0.9, 0.85]])
    pol = BayesPolicy(("weak", "strong"), p, np.array([1.0, 1.0]), objective.SCORE, 8, tmp_path / "b.json",
                      cache=tmp_path)
    for t in range(3):
        pol.observe(Transition(mdp.START if t == 0 else 31, 2, 3, None, 2 * 27 + 4, False))
    snap = pol.snapshot()
    saved = json.loads((tmp_path / "b.json").read_text())["payload"]
    # a resumed session: the participant file (3 turns at level 3) is read as carried, then the checkpoint
    again = BayesPolicy(("weak", "strong"), p, np.array([1.0, 1.0]), objective.SCORE, 8, tmp_path / "b.json",
                        saved=saved, cache=tmp_path)
    again.restore(snap)
    assert again.carried.sum() == 0 and again.counts.tolist() == [0, 0, 0, 0, 3, 0, 0, 0]
    assert again.decide() == pol.decide()


def test_a_session_at_one_level_says_why_in_its_summary(tmp_path):
    """Issue 29: `run --policy bayes` on the demo's strong participant plays level 2 throughout; the summary says
    why (each level's expected value now, and that the likeliest user models differ only where it did not play)."""
    from nao_trainer.core import objective
    from nao_trainer.policies.bayes import BayesPolicy

    p = np.array([[0.99, 0.95, 0.2, 0.05], [0.99, 0.93, 0.9, 0.85]])
    pol = BayesPolicy(("weak", "strong"), p, np.array([3.0, 1.0]), objective.SCORE, 6, None, cache=tmp_path)
    level2 = 1 * 27 + 4  # (level 2, no feedback, previous result 0): index of core.mdp
    for t in range(5):
        pol.observe(Transition(mdp.START if t == 0 else level2, 1, 2, None, level2, False))
    summary = pol.status()["summary"]
    assert "It played level 2 in all 5 turns, the highest expected value per turn under the posterior (now L1 " in summary
    assert "succeed at level 2 alike (user model weak 0.95, user model strong 0.93) and differ most at level 4 (0.05, 0.85)" in summary
    pol.observe(Transition(level2, 3, -1, None, 3 * 27 + 4, False))
    assert "It played" not in pol.status()["summary"]  # several levels: nothing to explain
