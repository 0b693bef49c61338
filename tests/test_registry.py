"""The plug-in registry: lazy entry points, one registration per name, entry-point groups, one-line errors."""
from __future__ import annotations

import sys
from types import SimpleNamespace

import pytest

from nao_trainer import registry
from nao_trainer.errors import ConfigError


@pytest.fixture
def tiny_module(monkeypatch):
    module = SimpleNamespace(Tiny=lambda *a, **k: ("made", a, k))
    monkeypatch.setitem(sys.modules, "tiny_plugin_for_registry_test", module)
    yield module
    registry.unregister("task", "tiny")


def test_an_entry_point_is_imported_only_when_asked_for(tiny_module):
    registry.register("task", "tiny", "tiny_plugin_for_registry_test:Tiny", origin="tests")
    assert "tiny" in registry.names("task")
    assert registry.make("task", "tiny", 1, x=2) == ("made", (1,), {"x": 2})


def test_a_name_is_registered_once(tiny_module):
    registry.register("task", "tiny", "tiny_plugin_for_registry_test:Tiny")
    with pytest.raises(ValueError, match="registered already"):
        registry.register("task", "tiny", "elsewhere:Other")
    registry.register("task", "tiny", "elsewhere:Other", override=True)
    assert registry.spec("task", "tiny").entry_point == "elsewhere:Other"


def test_an_unknown_name_says_what_is_installed():
    with pytest.raises(ConfigError, match=r"unknown task 'nope'.*installed: .*nao-trainer plugins"):
        registry.spec("task", "nope")


def test_a_missing_module_is_one_line():
    registry.register("policy", "ghost", "no_such_module_for_registry_test:Ghost")
    try:
        with pytest.raises(ConfigError, match="policy 'ghost' .* cannot be loaded"):
            registry.load("policy", "ghost")
    finally:
        registry.unregister("policy", "ghost")


@pytest.mark.parametrize("entry", ["nocolon", ":Attr", ""])
def test_a_malformed_entry_point_is_refused(entry):
    with pytest.raises(ValueError, match="module:attribute"):
        registry.register("task", "bad", entry)


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="registry kind"):
        registry.names("robot")


def test_the_default_of_a_kind_is_written_once_and_the_settings_declare_it():
    """A config that names no task, EEG device or robot model gets ``registry.default(kind)``: the settings
    declare it (the config reference shows it), and a kind a config always names has none."""
    from nao_trainer.core.settings import declared
    from nao_trainer.eeg.settings import EEGSettings
    from nao_trainer.session.config import RobotSection
    from nao_trainer.tasks.settings import TaskSettings

    assert {kind: registry.default(kind) for kind in registry.DEFAULTS} == {
        "task": "sequence", "eeg_device": "muse", "robot_model": "nao"}
    for cls, key, kind in ((TaskSettings, "name", "task"), (EEGSettings, "device", "eeg_device"),
                           (RobotSection, "model", "robot_model")):
        assert dict((k, d) for k, d, _ in declared(cls))[key] == registry.default(kind)
        assert registry.default(kind) in registry.names(kind)
    with pytest.raises(ValueError, match="policy has no default"):
        registry.default("policy")
    with pytest.raises(ValueError, match="registry kind must be one of"):
        registry.default("headband")
