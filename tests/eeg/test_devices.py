"""EEG devices as plug-ins: a device's montage (channels, rate, thresholds, stream match) and settings are
read alike by the inlet, the monitor, ``check`` and the offline pipeline; the Muse is one device."""
from __future__ import annotations

import json
import os
import sys
import time
import uuid
from types import SimpleNamespace

import numpy as np
import pytest

from nao_trainer import registry
from nao_trainer.core.engagement import QualityThresholds
from nao_trainer.core.montage import Montage
from nao_trainer.core.settings import SettingError
from nao_trainer.data import own
from nao_trainer.eeg.device import EEGDevice, Source
from nao_trainer.eeg.devices.muse import MuseDevice, MuseSettings
from nao_trainer.eeg.factory import open_monitor
from nao_trainer.eeg.inlet import StreamQuery
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.eeg.simulated_muse import SimulatedMuse
from nao_trainer.errors import ConfigError

configure_lsl("machine")

FAST = {"window_s": 1.0, "hop_s": 0.25, "loss_timeout_s": 0.5, "resolve_timeout_s": 5.0}


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _phase(monitor, phase, turn, seconds):
    monitor.begin_phase(phase, turn)
    monitor.mark(f"{phase}_start", turn)
    time.sleep(seconds)
    return monitor.end_phase()


def test_the_muse_is_a_registered_device_with_its_montage_and_settings():
    assert registry.load("eeg_device", "muse") is MuseDevice
    eeg = EEGSettings.from_mapping({})
    assert eeg.device == "muse"
    montage = eeg.eeg_device().montage()
    assert montage.labels == ("TP9", "AF7", "AF8", "TP10") and montage.rate_hz == 256.0
    assert montage.prefer_name == "Muse" and montage.thresholds == QualityThresholds()
    tuned = EEGSettings.from_mapping({"device_settings": {"max_std_uv": 80}}).eeg_device().montage()
    assert tuned.thresholds.max_std_uv == 80.0


@pytest.mark.parametrize("section, match", [
    ({"device": "nope"}, r"key 'eeg.device' unknown EEG device 'nope'.*installed: .*muse"),
    ({"device_settings": {"max_std_uv": -1}}, r"key 'eeg.device_settings.max_std_uv' must be > 0"),
    ({"device_settings": {"bord": 38}}, r"eeg.device_settings.bord"),
    ({"device_settings": {"min_std_uv": 50, "max_std_uv": 20}}, r"min_std_uv < max_std_uv"),
])
def test_a_wrong_device_or_device_setting_is_one_line_naming_the_key(section, match):
    with pytest.raises((ConfigError, SettingError, ValueError), match=match):
        EEGSettings.from_mapping(section)


def test_a_montage_keeps_its_channels_by_label_and_says_when_it_guesses():
    m = Montage("tiny", ("AF7", "AF8"), 256.0)
    assert m.scalp_index(["TP9", "af7", "AF8", "TP10", "Right AUX"], 5) == ((1, 2), ("af7", "AF8"), "")
    idx, labels, warning = m.scalp_index(["a", "b", "c"], 3)
    assert idx == (0, 1) and labels == ("AF7", "AF8") and "none of the tiny channel labels" in warning


class TinyDevice(EEGDevice):
    """A two-channel device for the test: AF7/AF8 of a Muse-like stream named Tiny, strict thresholds."""

    Settings = MuseSettings
    start_hint = "start the tiny headband"

    def montage(self, simulated=False):
        return Montage(self.name, ("AF7", "AF8"), 256.0, QualityThresholds(max_std_uv=2.0), prefer_name="Tiny",
                       board="tiny test board")

    def open(self, eeg, rng, *, simulated, rest_target=0.5):
        sim = SimulatedMuse.start(np.random.default_rng(int(rng.integers(1 << 30))), name="Tiny",
                                  source_id=_uid("tiny"), scope=eeg.lsl_scope)
        return Source(StreamQuery("EEG", None, sim.source_id, "Tiny"), self.montage(simulated), sim)


@pytest.fixture
def tiny_device(monkeypatch):
    monkeypatch.setitem(sys.modules, "tiny_eeg_device_for_test", SimpleNamespace(TinyDevice=TinyDevice))
    registry.register("eeg_device", "tiny", "tiny_eeg_device_for_test:TinyDevice", origin="tests")
    yield
    registry.unregister("eeg_device", "tiny")


def test_a_plugged_in_device_montage_reaches_the_inlet_monitor_and_offline_replay(tmp_path, tiny_device):
    cfg = {"mode": "simulated", "device": "tiny", "processing": FAST}
    monitor = open_monitor("simulated", cfg, tmp_path, np.random.default_rng(3), pseudonym=_uid("P"))
    try:
        assert monitor.inlet.scalp_labels == ("AF7", "AF8")  # the inlet kept the device's channels only
        assert "AF7/AF8" in monitor.describe()
        phase = _phase(monitor, "listening", 1, 2.0)
        # the device's strict threshold (2 uV) makes every window "implausible": the monitor applied it
        assert phase.engagement is None and phase.quality == 0.0
        assert set(monitor.live()["channels"]) == {"AF7", "AF8"}
    finally:
        monitor.close()
    stream = json.loads((tmp_path / "eeg" / "stream.json").read_text())
    assert stream["device"] == "tiny" and stream["scalp_channels"] == ["AF7", "AF8"]
    assert stream["montage"]["thresholds"]["max_std_uv"] == 2.0 and stream["montage"]["board"] == "tiny test board"
    phases, notes = own.replay_phases(tmp_path)  # the offline pipeline applies the thresholds recorded
    assert notes == [] and len(phases) == 1
    assert phases[0].engagement is None and phases[0].quality == 0.0, phases[0]
