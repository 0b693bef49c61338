"""The live engagement monitor over real LSL streams (machine scope): engagement, quality, loss, markers."""
from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from nao_trainer.eeg.inlet import StreamQuery
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.markers import MarkerOutlet, event_name, marker_source_id
from nao_trainer.core.eeg import Processing
from nao_trainer.eeg.factory import open_monitor
from nao_trainer.eeg.monitor import LslMonitor
from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.eeg.simulated_muse import SimulatedMuse
from nao_trainer.errors import ConfigError, EEGUnavailable
from nao_trainer.ports import NullMonitor

configure_lsl("machine")

FAST = {"window_s": 1.0, "hop_s": 0.25, "loss_timeout_s": 0.5, "resolve_timeout_s": 5.0}


def _uid(prefix: str) -> str:
    return f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _phase(monitor, phase: str, turn, seconds: float, target: float | None = None):
    if target is not None:
        monitor.set_target(target)
    monitor.begin_phase(phase, turn)  # as the session does: the phase, then its marker
    monitor.mark(f"{phase}_start", turn)
    time.sleep(seconds)
    monitor.mark(f"{phase}_end", turn)
    return monitor.end_phase()


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _simulated(tmp_path, seed=1, **processing):
    cfg = {"mode": "simulated", "processing": {**FAST, **processing}}
    return open_monitor("simulated", cfg, tmp_path, np.random.default_rng(seed), pseudonym=_uid("P"))


def test_beta_dominant_phases_score_higher(tmp_path):
    monitor = _simulated(tmp_path)
    try:
        assert isinstance(monitor, LslMonitor) and monitor.available
        base = _phase(monitor, "baseline", None, 2.5, target=0.5)
        assert base.index is not None
        high = _phase(monitor, "listening", 1, 2.0, target=1.0)
        low = _phase(monitor, "listening", 2, 2.0, target=0.0)
        answer = _phase(monitor, "answer", 2, 1.0, target=0.0)
    finally:
        monitor.close()
    assert high.index > 1.5 * low.index, (high, low)
    assert high.engagement is not None and low.engagement is not None
    # Each phase is normalised with the bounds of the task windows seen up to it; the baseline is the
    # reference, not part of the range (issue 22). The first task phase (8 windows here) is thus scaled
    # over itself and lies mid-scale, and as half of each 2 s phase is the smoothed index gliding from
    # the previous target, the two phase values are close (0.48 and 0.49 in one run): comparing them is a
    # coin toss. Once the glide is over, on the common scale both phases reach, the beta-dominant phase
    # lies at the top and the other near the bottom.
    common = monitor.normaliser.normalise
    assert common(high.series[-2:]).mean() > common(low.series[-2:]).mean() + 0.5
    assert 0.0 <= low.engagement <= 1.0 and 0.0 <= high.engagement <= 1.0
    assert high.quality == pytest.approx(1.0, abs=0.2) and high.reason == ""
    assert len(high.series) >= 4 and np.isfinite(high.series).all()
    assert answer.index is not None
    # the per-phase series and summaries are in the session folder
    phases = _rows(tmp_path / "eeg" / "phases.csv")
    assert [(r["turn"], r["phase"]) for r in phases] == [("", "baseline"), ("1", "listening"), ("2", "listening"),
                                                           ("2", "answer")]
    assert float(phases[1]["engagement_index"]) == pytest.approx(high.index, rel=1e-5)
    windows = _rows(tmp_path / "eeg" / "windows.csv")
    assert sum(r["turn"] == "1" and r["phase"] == "listening" for r in windows) == len(high.series)
    raw = (tmp_path / "eeg" / "raw.csv").read_text().splitlines()
    assert raw[0] == "lsl_time,TP9,AF7,AF8,TP10" and len(raw) > 256 * 6
    # (a simulated Muse starved of CPU beside another suite was once "lost" and "restored" 1 s later: the
    # monitor's right reaction, not this test's subject)
    events = [r["event"] for r in _rows(tmp_path / "eeg" / "events.csv")
              if r["event"] not in ("eeg_stream_lost", "eeg_stream_restored")]
    assert events[:3] == ["eeg_stream_found", "baseline_start", "baseline_end"]
    assert "turn_1_listening_start" in events and "turn_2_answer_end" in events


def test_bad_channels_are_excluded_and_all_bad_gives_no_value(tmp_path):
    monitor = _simulated(tmp_path, seed=2)
    try:
        _phase(monitor, "baseline", None, 1.5)
        monitor.simulator.set_fault(1, "flat")
        time.sleep(1.0)  # let the windows fill with the fault
        one_bad = _phase(monitor, "listening", 1, 1.5)
        for ch, kind in ((0, "saturated"), (2, "flat"), (3, "saturated")):
            monitor.simulator.set_fault(ch, kind)
        time.sleep(1.0)
        all_bad = _phase(monitor, "listening", 2, 1.5)
    finally:
        monitor.close()
    assert one_bad.index is not None and 0.5 <= one_bad.quality <= 0.8, one_bad
    assert all_bad.engagement is None and all_bad.index is None
    assert all_bad.quality == 0.0
    assert "clean" in all_bad.reason and "flat" in all_bad.reason and "saturated" in all_bad.reason
    row = _rows(tmp_path / "eeg" / "phases.csv")[-1]
    assert row["engagement"] == "" and "flat" in row["reason"]


def test_no_stream_required_refuses_with_clear_message(tmp_path):
    cfg = {"mode": "lsl", "required": True, "stream_name": _uid("absent"), "processing": {"resolve_timeout_s": 0.3}}
    with pytest.raises(EEGUnavailable) as err:
        open_monitor("lsl", cfg, tmp_path, np.random.default_rng(0))
    msg = str(err.value)
    assert "no EEG stream" in msg and "muselsl" in msg and "simulate-muse" in msg and "\n" not in msg


def test_no_stream_not_required_marks_unavailable_then_attaches(tmp_path):
    name = _uid("late")
    cfg = {"mode": "lsl", "stream_name": name, "processing": {**FAST, "resolve_timeout_s": 0.3}}
    monitor = open_monitor("lsl", cfg, tmp_path, np.random.default_rng(0), pseudonym=_uid("P"))
    sim = None
    try:
        assert monitor.status == "unavailable"
        none = _phase(monitor, "listening", 1, 0.2)
        assert none.engagement is None and none.index is None and none.quality == 0.0
        assert none.reason.startswith("EEG unavailable") and "no EEG stream" in none.reason
        sim = SimulatedMuse.start(np.random.default_rng(4), name=name, source_id=_uid("MuseLate"))
        deadline = time.monotonic() + 60  # a hang limit
        while not monitor.available and time.monotonic() < deadline:
            time.sleep(0.1)
        assert monitor.available, "the monitor did not attach to the stream that appeared"
        assert monitor.wait_for_windows(1, 60), "no EEG window within 60 s of attaching"
        # A short phase (a few windows, fewer than a scale needs). Beside another suite the simulated Muse
        # can be starved through all 0.6 s of it, leaving no window: then another short phase, as a hang limit.
        for turn in range(2, 22):
            later = _phase(monitor, "listening", turn, 0.6)
            if later.index is not None:
                break
        assert later.index is not None, later.reason
        # no baseline: running bounds only, and too few windows yet for a scale - said, not guessed
        assert later.engagement is None and later.reason.startswith("no normalisation scale yet")
    finally:
        monitor.close()
        if sim is not None:
            sim.stop()


@pytest.mark.slow
def test_stream_lost_and_back_mid_session(tmp_path):
    monitor = _simulated(tmp_path, seed=3)
    try:
        _phase(monitor, "baseline", None, 1.5)
        # 2 s phases, not 1 s: a loaded machine starves the simulated headband's thread for a while, and a 1 s
        # phase was then only 40 % clean signal (seen with two suites side by side), as a real one may be
        ok = _phase(monitor, "listening", 1, 2.0)
        assert ok.index is not None, ok
        sid = monitor.simulator.source_id
        monitor.begin_phase("listening", 2)
        monitor.simulator.stop()  # the headband drops out mid-phase
        time.sleep(1.5)
        lost = monitor.end_phase()  # no exception escapes
        assert monitor.status == "lost"
        assert lost.engagement is None and lost.index is None
        assert lost.reason.startswith("stream lost") and lost.quality < 0.5
        # the same source comes back: the inlet recovers by itself
        monitor.simulator = SimulatedMuse.start(np.random.default_rng(5), source_id=sid)
        deadline = time.monotonic() + 60  # a hang limit: liblsl resumes ~1.5 s after the outlet returns
        while not monitor.available and time.monotonic() < deadline:
            time.sleep(0.1)
        assert monitor.available, "samples did not resume after the stream returned"
        time.sleep(1.5)
        back = _phase(monitor, "listening", 3, 2.0)
        assert back.index is not None and back.quality >= 0.5, back
    finally:
        monitor.close()
    gaps = _rows(tmp_path / "eeg" / "gaps.csv")
    # the headband's drop-out is one gap; a loaded machine may add a spurious "lost" of ~0 s of stamps
    # (the reader starved past loss_timeout_s while samples kept their stamps), which is not a gap in the data
    assert len([g for g in gaps if float(g["duration_s"]) > 1.0]) == 1, gaps
    assert all(float(g["duration_s"]) < 0.5 for g in gaps if float(g["duration_s"]) <= 1.0), gaps
    events = [r["event"] for r in _rows(tmp_path / "eeg" / "events.csv")]
    assert events.index("eeg_stream_lost") < events.index("eeg_stream_restored")
    phases = _rows(tmp_path / "eeg" / "phases.csv")
    assert float(phases[2]["lost_s"]) > 1.0 and phases[2]["reason"].startswith("stream lost")


def test_markers_reach_an_lsl_inlet(tmp_path):
    import pylsl

    pseudonym = _uid("P")
    sid = marker_source_id(pseudonym)
    outlet = MarkerOutlet(sid)
    try:
        found = pylsl.resolve_bypred(f"type='Markers' and source_id='{sid}'", 1, 5.0)
        assert found and found[0].name() == "Markers" and found[0].channel_format() == pylsl.cf_string
        assert found[0].nominal_srate() == pylsl.IRREGULAR_RATE
        inlet = pylsl.StreamInlet(found[0])
        inlet.open_stream(5.0)
        assert outlet_wait(outlet)
        t_push = outlet.push("session_start")
        outlet.push("listening_start", 3)
        got = []
        deadline = time.monotonic() + 5
        while len(got) < 2 and time.monotonic() < deadline:
            sample, ts = inlet.pull_sample(0.5)
            if sample:
                got.append((sample[0], ts))
        assert [g[0] for g in got] == ["session_start", "turn_3_listening_start"]
        assert got[0][1] == pytest.approx(t_push, abs=1e-3)
        del inlet
    finally:
        outlet.close()
    assert outlet.push("late") == 0.0  # closed: nothing published, no error
    assert event_name("listening_end", 7) == "turn_7_listening_end"
    assert event_name("turn_start", 7) == "turn_7_start" and event_name("session_end") == "session_end"
    assert sid == f"nao-trainer-markers-{pseudonym}"


def outlet_wait(outlet: MarkerOutlet, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if outlet.has_consumers():
            return True
        time.sleep(0.05)
    return False


def test_settings_validation_names_the_key():
    assert EEGSettings.from_mapping(None, "lsl").processing == Processing()
    s = EEGSettings.from_mapping({"stream_name": "Muse", "processing": {"window_s": 4, "record_raw": False}}, "lsl")
    assert s.processing.window_s == 4.0 and s.stream_name == "Muse" and s.lsl_scope == "machine"
    cases = [
        # one validator and one message style for every section (core.settings)
        ({"processing": {"windw_s": 2}}, "unknown key 'eeg.processing.windw_s'; did you mean 'eeg.processing.window_s'"),
        ({"processing": {"window_s": "2"}}, "key 'eeg.processing.window_s' must be a number, got '2'"),
        ({"processing": {"window_s": 1.0, "hop_s": 2.0}}, "key 'eeg.processing.hop_s' must not exceed window_s"),
        ({"processing": {"ewma_a": 1.5}}, "key 'eeg.processing.ewma_a' must be <= 0.999, got 1.5"),
        ({"processing": {"min_clean_channels": 2.5}}, "key 'eeg.processing.min_clean_channels' must be an integer"),
        ({"processing": {"record_raw": "yes"}}, "key 'eeg.processing.record_raw' must be true/false"),
        ({"lsl_scope": "planet"}, "key 'eeg.lsl_scope' must be one of"),
        ({"stream_nam": "Muse"}, "unknown key 'eeg.stream_nam'; did you mean 'eeg.stream_name'"),
        ({"required": "yes"}, "key 'eeg.required' must be true/false"),
        ({"stream_name": "Mu'se"}, "key 'eeg.stream_name' must not contain a quote"),
    ]
    for cfg, message in cases:
        with pytest.raises(ConfigError, match=re.escape(message)):
            EEGSettings.from_mapping(cfg, "lsl")
    with pytest.raises(ConfigError, match="eeg.mode"):
        EEGSettings.from_mapping({}, "bluetooth")


def test_off_mode_is_the_null_monitor(tmp_path):
    monitor = open_monitor("off", {}, tmp_path, np.random.default_rng(0))
    assert isinstance(monitor, NullMonitor)
    assert monitor.end_phase().reason == "EEG off"
    assert not (tmp_path / "eeg").exists()


def test_unusable_stream_is_reported_not_raised(tmp_path):
    """An EEG-typed stream without a sampling rate: refused when required, 'unavailable' otherwise."""
    import pylsl

    name = _uid("irregular")
    outlet = pylsl.StreamOutlet(pylsl.StreamInfo(name, "EEG", 4, pylsl.IRREGULAR_RATE, pylsl.cf_float32, _uid("irr")))
    try:
        cfg = {"mode": "lsl", "stream_name": name, "processing": {"resolve_timeout_s": 3.0}}
        with pytest.raises(EEGUnavailable, match="irregular rate"):
            open_monitor("lsl", {**cfg, "required": True}, tmp_path, np.random.default_rng(0))
        monitor = open_monitor("lsl", cfg, tmp_path, np.random.default_rng(0), pseudonym=_uid("P"))
        try:
            result = _phase(monitor, "listening", 1, 0.1)
            assert result.engagement is None and "irregular rate" in result.reason
        finally:
            monitor.close()
        monitor.mark("after_close")  # closed: ignored, no error
        assert monitor.end_phase().reason == "no EEG phase was open"
    finally:
        del outlet


def test_missing_lsl_config_file_is_refused(monkeypatch, tmp_path):
    """A mistyped LSLAPICFG would silently widen discovery beyond the machine: refuse it."""
    from nao_trainer.eeg import lsl_scope

    monkeypatch.setattr(lsl_scope, "_configured", None)
    monkeypatch.setenv("LSLAPICFG", str(tmp_path / "missing.cfg"))
    with pytest.raises(ConfigError, match="LSLAPICFG=.*missing.cfg: no such file"):
        lsl_scope.configure_lsl("machine")
    with pytest.raises(ValueError, match="LSL scope must be one of"):
        lsl_scope.configure_lsl("planet")


def test_reader_errors_are_logged_not_raised(tmp_path):
    monitor = _simulated(tmp_path, seed=6)
    try:
        real_push, calls = monitor.engine.push, {"n": 0}

        def failing_push(x, ts):
            calls["n"] += 1
            if calls["n"] <= 3:
                raise RuntimeError("injected failure")
            return real_push(x, ts)

        monitor.engine.push = failing_push
        deadline = time.monotonic() + 60  # a hang limit: the reader pushes every chunk (~20 per second)
        while calls["n"] <= 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert calls["n"] > 3 and monitor.errors == 3 and monitor._thread.is_alive()
        time.sleep(1.0)
        result = _phase(monitor, "listening", 1, 1.0)
        assert result.index is not None
    finally:
        monitor.close()
    errors = [r for r in _rows(tmp_path / "eeg" / "events.csv") if r["event"] == "eeg_error"]
    assert len(errors) == 3 and "injected failure" in errors[0]["detail"]


def _bare_monitor(now: list[float]) -> LslMonitor:
    """An LslMonitor without a reader thread or LSL: windows are fed by the test, the clock is ``now[0]``."""
    import threading
    from types import SimpleNamespace

    from nao_trainer.core.phase import EngagementNormaliser
    from nao_trainer.eeg.session_files import SessionFiles

    m = LslMonitor.__new__(LslMonitor)
    m._clock = lambda: now[0]
    m.settings = EEGSettings()
    m.proc = m.settings.processing
    m.files, m.normaliser = SessionFiles(None), EngagementNormaliser()
    m.windows, m.gaps, m.phases = [], [], []
    m.inlet, m.unavailable_reason, m._lost = SimpleNamespace(), "", False
    m._phase, m._had_baseline, m._started, m._raw_pending = None, False, 0.0, []
    m._cond, m._urgent = threading.Condition(), threading.Event()
    m._last_stamp = -np.inf
    return m


def _windows(t0: float, t1: float, hop: float, rng) -> list:
    from nao_trainer.core.engagement import WindowResult

    ts = np.arange(t0 + hop, t1 + 1e-9, hop)
    return [WindowResult(float(t), float(v), float(v), 1.0) for t, v in zip(ts, rng.uniform(0.3, 0.9, len(ts)))]


def test_end_phase_keeps_early_windows_of_a_long_phase_while_the_reader_prunes():
    now = [0.0]
    m = _bare_monitor(now)
    m.begin_phase("listening", 1)
    m.windows = _windows(0.0, 100.1, 0.025, np.random.default_rng(0))  # > 4000: the reader prunes
    n = len(m.windows)
    now[0] = m._last_stamp = 100.2
    collect = m._windows_until

    def reader_prunes_meanwhile(t0, t1):  # the reader thread runs _prune while end_phase waits
        m._prune()
        return collect(t0, t1)

    m._windows_until = reader_prunes_meanwhile
    assert len(m.end_phase().series) == n > 4000 and m._phase is None


def test_no_scale_reason_says_baseline_too_short_and_phase_value_matches_core():
    from nao_trainer.core.phase import aggregate_phase

    rng = np.random.default_rng(1)
    now = [0.0]
    m = _bare_monitor(now)
    m.begin_phase("baseline", None)
    m.windows = _windows(0.0, 0.5, 0.25, rng)  # 2 windows: too short for a scale
    now[0] = m._last_stamp = 0.5
    m.end_phase()
    m.begin_phase("listening", 1)
    m.windows += _windows(0.5, 0.75, 0.25, rng)
    now[0] = m._last_stamp = 0.75
    r = m.end_phase()
    assert r.engagement is None and r.index is not None
    assert r.reason == "no normalisation scale yet (1 task windows seen, 5 needed; baseline too short: 2 usable windows)"
    # the phase value is the core's (normalised once, not twice)
    m.begin_phase("listening", 2)
    m.windows += _windows(0.75, 3.0, 0.25, rng)
    now[0] = m._last_stamp = 3.0
    r = m.end_phase()
    want = aggregate_phase([w for w in m.windows if w.t_end > 0.75], 0.75, 3.0, 0.25, m.normaliser)
    assert r.engagement is not None and r.engagement == want.engagement and r.index == want.index


def test_stream_query_pick_prefers_the_muse_name():
    from types import SimpleNamespace

    def info(name):
        return SimpleNamespace(name=lambda: name)

    q = StreamQuery()
    a, muse, b = info("OpenBCI"), info("Muse"), info("Other")
    assert q.pick([a, muse, b]) is muse and q.pick([a, b]) is a and q.pick([]) is None
    assert StreamQuery(prefer_name="Other").pick(iter([a, muse, b])) is b


def test_live_view_reports_the_index_and_each_channels_contact(tmp_path):
    # What the supervisor console shows: the latest index and, per channel, whether it is clean.
    monitor = _simulated(tmp_path, seed=3)
    try:
        deadline = time.monotonic() + 10
        while (monitor.live() or {}).get("index") is None and time.monotonic() < deadline:
            time.sleep(0.05)
        good = monitor.live()
        monitor.simulator.set_fault(1, "flat")
        time.sleep(1.5)
        faulty = monitor.live()
    finally:
        monitor.close()
    assert good["status"] == "streaming" and good["index"] is not None
    names = list(good["channels"])
    assert len(names) == 4 and all(good["channels"].values())
    assert faulty["channels"][names[1]] is False and sum(faulty["channels"].values()) == 3
    assert NullMonitor().live() is None


MANY_OUTLETS = """
import sys, pylsl
from nao_trainer.eeg.lsl_scope import configure_lsl
configure_lsl("machine")
outlets = [pylsl.StreamOutlet(pylsl.StreamInfo(f"many{i}", "Probe", 1, 10, "float32", f"{sys.argv[1]}-{i}"))
           for i in range(40)]
print("ready", flush=True)
sys.stdin.readline()
"""

FIND = """
import sys, time, pylsl
from nao_trainer.eeg.lsl_scope import configure_lsl
configure_lsl("machine")
wanted = set(sys.argv[1:])
resolver = pylsl.ContinuousResolver(pred=" or ".join(f"source_id='{s}'" for s in sorted(wanted)))
deadline = time.monotonic() + 20
while time.monotonic() < deadline and {i.source_id() for i in resolver.results()} != wanted:
    time.sleep(0.05)
print(" ".join(sorted(wanted - {i.source_id() for i in resolver.results()})) or "all found")
"""


def test_the_projects_machine_scope_finds_a_stream_beyond_liblsls_default_32_ports():
    """Machine scope asks each port of liblsl's range on 127.0.0.1; with the default 32, an outlet beyond
    them (the 40th of a process here; any beyond 32 on the machine) binds a random port and another process
    never finds it. The project's config (no LSLAPICFG) widens the range. 40 outlets on loopback, pinned."""
    env = {k: v for k, v in os.environ.items() if k != "LSLAPICFG"}
    tag = _uid("many")
    owner = subprocess.Popen([sys.executable, "-c", MANY_OUTLETS, tag], env=env, stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert owner.stdout.readline().strip() == "ready"
        res = subprocess.run([sys.executable, "-c", FIND, *(f"{tag}-{i}" for i in range(40))], env=env,
                             capture_output=True, text=True, timeout=120)
    finally:
        owner.communicate("\n", timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "all found"  # else: the source_ids not found
