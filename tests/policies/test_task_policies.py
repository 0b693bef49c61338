"""Issue 26: the policies that take the shipped user models, priors or trained policies (fitted on the published data,
the sequence task's) take a task's own simulated users under another task (n-back), or are refused in one line
naming the task; under the sequence task they are what they were."""
from __future__ import annotations

import numpy as np
import pytest

from nao_trainer.core import bayes
from nao_trainer.core.posterior import level_means
from nao_trainer.errors import ConfigError
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.policies.factory import make_policy, offline_policy
from nao_trainer.session.config import load_config
from nao_trainer.tasks.base import COMMON_COLUMNS
from nao_trainer.tasks.nback import NBackTask
from nao_trainer.tasks.sequence import SequenceTask

NBACK_STUDY = PROJECT_ROOT / "config" / "studies" / "nback.yaml"


def _policy(tmp_path, task, **overrides):
    config = load_config(NBACK_STUDY, {**{f"policy.{k}": v for k, v in overrides.items()}, "policy.state_path": "{session}"})
    return make_policy(config.policy, "P1", tmp_path, turns=10, task=task)


def test_personalised_under_nback_matches_the_tasks_own_simulated_users(tmp_path):
    task = NBackTask()
    users = task.simulated_users()
    policy = _policy(tmp_path, task, kind="personalised")
    assert policy.models.names == tuple(name for name, _ in users)
    assert np.allclose(level_means(policy.models.p_success), [rates for _, rates in users])
    # level-only users: each one's best policy is a fixed level, so the candidates are the four levels
    assert [c.name for c in policy.pers.candidates] == ["fixed:1", "fixed:2", "fixed:3", "fixed:4"]
    shipped = _policy(tmp_path, SequenceTask(), kind="personalised")  # the sequence task: the fitted clusters
    assert set(shipped.models.names).isdisjoint(policy.models.names)
    assert any(c.name.startswith("usp:") for c in shipped.pers.candidates)
    assert shipped.fingerprint != policy.fingerprint  # a saved state of the one is refused by the other


@pytest.mark.skipif(not bayes.available(), reason="the planner needs numba")
def test_bayes_under_nback_plans_over_the_tasks_users_and_refuses_a_shipped_prior(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    task = NBackTask()
    policy = _policy(tmp_path, task, kind="bayes")
    assert policy.names == tuple(name for name, _ in task.simulated_users())
    assert np.allclose(policy.p, [rates for _, rates in task.simulated_users()], atol=1e-9)
    assert "nback" in policy.prior
    for prior in ("clusters", "psychometric"):
        with pytest.raises(ConfigError, match=f"policy 'bayes' under task 'nback': prior '{prior}' is fitted on the "
                                              "sequence task's data") as exc:
            _policy(tmp_path, task, kind="bayes", prior=prior)
        assert "\n" not in str(exc.value)


def test_a_trained_policy_under_nback_is_refused_in_one_line(tmp_path):
    config = load_config(NBACK_STUDY, {"policy.kind": "usp:2"})
    for build in (lambda: make_policy(config.policy, "P1", tmp_path, turns=10, task=NBackTask()),
                  lambda: offline_policy(config.policy, 10, NBackTask())):
        with pytest.raises(ConfigError, match=r"policy 'usp:2' under task 'nback': it is trained on a user model "
                                              r"fitted on the sequence task's data; use personalised or bayes") as exc:
            build()
        assert "\n" not in str(exc.value)


def test_a_task_without_simulated_users_is_refused_for_the_model_based_policies(tmp_path):
    class Plain:  # a lab's task that is not the published data's and declares no simulated users
        name, levels, columns = "plain", (1, 2, 3, 4), COMMON_COLUMNS

    for kind in ("personalised", "bayes"):
        if kind == "bayes" and not bayes.available():
            continue
        with pytest.raises(ConfigError, match=f"policy '{kind}' under task 'plain': .* declares no simulated users "
                                              "of its own .*; use schedule or random"):
            _policy(tmp_path, Plain(), kind=kind)
