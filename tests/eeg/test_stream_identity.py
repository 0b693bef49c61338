"""Issue 17, "the right signal": simulated and replayed streams say what they are; a person's session refuses them.

Real LSL streams on this machine, each pinned by a unique source_id.
"""
from __future__ import annotations

import json
import os
import uuid
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.eeg.factory import open_monitor
from nao_trainer.eeg.inlet import EEGInlet, StreamQuery, acquisition, resolve_all, resolve_eeg
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.settings import EEGSettings, ambiguous_streams, simulated_refusal
from nao_trainer.eeg.simulated_muse import ReplayMuse, SimulatedMuse
from nao_trainer.errors import ConfigError, EEGUnavailable

configure_lsl("machine")
FAST = {"window_s": 1.0, "hop_s": 0.25, "loss_timeout_s": 0.5, "resolve_timeout_s": 5.0}


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _own_session(tmp_path: Path) -> Path:
    """A minimal folder written by `run` with raw EEG, enough to replay."""
    folder = tmp_path / "P1_20260101-000000"
    (folder / "eeg").mkdir(parents=True)
    (folder / "session.json").write_text(json.dumps({"status": "completed"}))
    (folder / "eeg" / "stream.json").write_text(json.dumps({"nominal_srate": 256.0, "scalp_channels":
                                                            ["TP9", "AF7", "AF8", "TP10"]}))
    rng = np.random.default_rng(0)
    lines = ["lsl_time,TP9,AF7,AF8,TP10"] + [",".join([repr(i / 256)] + [repr(float(v)) for v in rng.normal(0, 10, 4)])
                                             for i in range(256 * 4)]
    (folder / "eeg" / "raw.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_simulated_and_replayed_streams_say_what_they_are_and_keep_a_muse_name(tmp_path):
    sim = SimulatedMuse.start(np.random.default_rng(1), source_id=_uid("MuseId"))
    rep = ReplayMuse.start(_own_session(tmp_path), source_id=_uid("MuseRep"), loop=True)
    try:
        for pub, kind in ((sim, "simulated"), (rep, "replayed")):
            info = resolve_eeg(StreamQuery("EEG", None, pub.source_id), 10.0)
            assert info is not None and info.name() == "Muse"
            inlet = EEGInlet.open(info)
            try:
                assert acquisition(inlet.inlet.info(2.0)) == kind
                ident = inlet.identity()
                assert ident["simulated"] is True and ident["acquisition"] == kind
                assert ident["source_id"] == pub.source_id and ident["channel_count"] == len(pub.labels)
                assert ident["type"] == "EEG" and ident["hostname"] and ident["nominal_srate"] == pub.fs
                assert inlet.describe()["simulated"] is True
            finally:
                inlet.close()
        full = EEGInlet.open(resolve_eeg(StreamQuery("EEG", None, rep.source_id), 10.0))
        try:
            assert full.inlet.info(2.0).desc().child_value("replay_of") == str(rep.origin)
            assert full.inlet.info(2.0).desc().child_value("manufacturer") == "nao-trainer"
        finally:
            full.close()
    finally:
        sim.stop()
        rep.stop()


def test_an_unmarked_stream_counts_as_a_device():
    import pylsl

    sid = _uid("Dev")
    info = pylsl.StreamInfo("Muse", "EEG", 4, 256, pylsl.cf_float32, sid)
    info.desc().append_child_value("manufacturer", "Muse")
    outlet = pylsl.StreamOutlet(info)
    try:
        inlet = EEGInlet.open(resolve_eeg(StreamQuery("EEG", None, sid), 10.0))
        try:
            assert inlet.identity()["simulated"] is False and inlet.identity()["acquisition"] == "device"
        finally:
            inlet.close()
    finally:
        del outlet


def test_refusal_rule_and_the_pilot_key():
    ident = {"name": "Muse", "source_id": "Muse00:55:DA:30:50:8A", "acquisition": "simulated", "simulated": True}
    msg = simulated_refusal(ident, EEGSettings(mode="lsl"))
    assert "simulated" in msg and "Muse00:55:DA:30:50:8A" in msg and "--allow-simulated-eeg" in msg and "\n" not in msg
    assert simulated_refusal(ident, EEGSettings.from_mapping({"allow_simulated": True}, "lsl")) == ""
    assert simulated_refusal(dict(ident, simulated=False), EEGSettings(mode="lsl")) == ""
    with pytest.raises(ConfigError, match="eeg.allow_simulated"):
        EEGSettings.from_mapping({"allow_simulated": "yes"}, "lsl")


def test_a_persons_session_refuses_a_simulated_stream_with_exit_4_unless_the_pilot_allows_it(tmp_path):
    sid = _uid("MuseSim")
    sim = SimulatedMuse.start(np.random.default_rng(2), source_id=sid)
    try:
        cfg = {"mode": "lsl", "source_id": sid, "required": False, "processing": FAST}
        with pytest.raises(EEGUnavailable) as err:
            open_monitor("lsl", cfg, tmp_path / "a", np.random.default_rng(0), pseudonym=_uid("P"), person=True)
        assert err.value.exit_code == 4 and "simulated" in str(err.value) and sid in str(err.value)
        assert not (tmp_path / "a" / "eeg" / "stream.json").exists()
        monitor = open_monitor("lsl", dict(cfg, allow_simulated=True), tmp_path / "b", np.random.default_rng(0),
                               pseudonym=_uid("P"), person=True)
        try:
            assert monitor.available and monitor.stream_identity["simulated"] is True
        finally:
            monitor.close()
        stream = json.loads((tmp_path / "b" / "eeg" / "stream.json").read_text())
        assert stream["simulated"] is True and stream["acquisition"] == "simulated" and stream["source_id"] == sid
        assert stream["type"] == "EEG" and stream["channel_count"] == 5 and stream["hostname"]
    finally:
        sim.stop()


def test_a_simulated_stream_appearing_later_is_not_attached_to_a_persons_session(tmp_path):
    sid = _uid("MuseLate")
    cfg = {"mode": "lsl", "source_id": sid, "processing": {**FAST, "resolve_timeout_s": 0.2}}
    monitor = open_monitor("lsl", cfg, tmp_path, np.random.default_rng(0), pseudonym=_uid("P"), person=True)
    sim = SimulatedMuse.start(np.random.default_rng(3), source_id=sid)
    try:
        events = tmp_path / "eeg" / "events.csv"
        import time

        deadline = time.monotonic() + 30  # an event wait, not a bound: the rejection is what is checked
        while time.monotonic() < deadline and not (events.exists() and "eeg_stream_rejected" in events.read_text()):
            time.sleep(0.1)
        assert "eeg_stream_rejected" in events.read_text() and "simulated" in events.read_text()
        assert not monitor.available and monitor.stream_identity is None
    finally:
        monitor.close()
        sim.stop()


def test_several_matching_streams_without_a_pin_are_ambiguous():
    import pylsl

    kind = _uid("EEGamb")
    outlets = [pylsl.StreamOutlet(pylsl.StreamInfo("Muse", kind, 4, 256, pylsl.cf_float32, _uid(f"k{i}")))
               for i in range(2)]
    try:
        infos = resolve_all(StreamQuery(kind), 10.0, settle_s=1.0)
        assert len(infos) == 2
        msg = ambiguous_streams(f"type {kind!r}", None, [(i.name(), i.source_id()) for i in infos])
        assert msg.startswith("2 EEG streams match") and all(i.source_id() in msg for i in infos)
        assert ambiguous_streams("x", infos[0].source_id(), [("Muse", "1"), ("Muse", "2")]) == ""
    finally:
        del outlets
