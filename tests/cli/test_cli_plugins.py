"""`nao-trainer plugins`: every registered plug-in with its origin and its settings (key, default, rule)."""
from __future__ import annotations

import json
import sys
from types import SimpleNamespace

from nao_trainer import registry
from nao_trainer.cli import main
from nao_trainer.policies import kinds


def test_plugins_lists_the_builtin_policies_and_eeg_devices_with_their_settings(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for name in ("schedule", "random", "usp", "personalised", "bayes"):
        assert f"\n  {name} " in out
    assert "policy.kappa = 10.0  (a number, >= 0.01)" in out
    assert "policy.objective = \"score\"" in out and "muse" in out
    assert "\n  sequence " in out and "\n  nao " in out and "robot.model_settings.cool_posture" in out  # every kind
    assert "(every policy) policy.kind, policy.learning, policy.state_path, policy.guidance" in out


def test_plugins_json_gives_origin_entry_point_and_every_declared_key(capsys):
    assert main(["plugins", "--kind", "policy", "--json"]) == 0
    found = {e["name"]: e for e in json.loads(capsys.readouterr().out)}
    bayes = found["bayes"]
    assert bayes["origin"] == "nao_trainer" and bayes["entry_point"] == "nao_trainer.policies.kinds:BAYES"
    assert [k["key"] for k in bayes["settings"]] == ["policy.objective", "policy.prior"]
    assert found["personalised"]["settings"][0] == {
        "key": "policy.assessment", "default": [2, 2, 3, 3, 4, 4], "doc": kinds.PersonalisedSettings.__dataclass_fields__[
            "assessment"].metadata["rule"].doc, "rule": "a list of integers, checked by check_assessment"}


def test_a_plugin_that_cannot_be_loaded_is_listed_with_why_and_exit_1(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "broken_policy_for_plugins_test", SimpleNamespace())
    registry.register("policy", "broken", "broken_policy_for_plugins_test:Missing", origin="a-lab-package")
    try:
        assert main(["plugins", "--kind", "policy"]) == 1
    finally:
        registry.unregister("policy", "broken")
    out = capsys.readouterr().out
    assert "broken         from a-lab-package" in out and "CANNOT BE LOADED" in out and "is broken" in out
