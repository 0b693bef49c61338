"""`nao-trainer check`: the robot (a stand-in process over qi), a real LSL EEG stream pinned by source_id, the disk."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import uuid

import numpy as np
import pytest

from nao_trainer.eeg.simulated_muse import SimulatedMuse
from nao_trainer.robot.naoqi import NaoqiRobot
from nao_trainer.robot.standin import spawn_standin
from nao_trainer.session.check import CheckResult, check_disk, exit_code


def check(*args: str, cwd=None) -> subprocess.CompletedProcess:
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    return subprocess.run([sys.executable, "-m", "nao_trainer", "check", *args], capture_output=True, text=True,
                          env=env, timeout=120, cwd=cwd)


@pytest.fixture(scope="module")
def standin():
    proc, url = spawn_standin(speed=50)
    yield url
    proc.send_signal(signal.SIGINT)
    proc.wait(10)


def study(tmp_path, eeg: str) -> str:
    path = tmp_path / "study.yaml"
    path.write_text(f"study: {{name: check}}\nanswers: {{input: tactile}}\neeg: {eeg}\n")
    return str(path)


def test_a_ready_robot_passes_and_a_quiet_muted_or_flat_one_fails_with_the_fix(standin, tmp_path):
    cfg = study(tmp_path, "{mode: \"off\"}")
    res = check("--config", cfg, "--robot", standin, "--out", str(tmp_path / "s"))
    lines = res.stdout.strip().splitlines()
    assert res.returncode == 0, res.stdout + res.stderr
    assert [ln.split()[:2] for ln in lines] == [["OK", "disk"], ["OK", "robot"], ["OK", "eeg"]]
    assert "12 services the task needs" in lines[1]  # the NAO model's 7 required and 5 optional ones
    assert "nao-standin (NAOqi 2.8.5.10), volume 60%, battery 85%, Autonomous Life solitary" in lines[1]
    assert ("battery 85% lasts ~51 min, the session needs ~11 min; LHipPitch 35 °C now, ~46 °C after ~11 min standing "
            "(estimate: +1 °C/min, hot at ~70 °C)") in lines[1]

    def failing(call: tuple, undo: tuple) -> str:
        robot = NaoqiRobot.connect(standin, 5.0)
        try:
            robot.call(*call)
            res = check("--config", cfg, "--robot", standin, "--out", str(tmp_path / "s"))
        finally:
            robot.call(*undo)
            robot.close()
        assert res.returncode == 3, res.stdout
        return res.stdout.strip().splitlines()[1]

    # A muted robot: the speech engine's gain still says 1.0, so only ALAudioDevice tells.
    line = failing(("ALAudioDevice", "muteAudioOut", True), ("ALAudioDevice", "muteAudioOut", False))
    assert line.startswith("FAIL robot") and "MUTED" in line and "fix: unmute the robot" in line
    line = failing(("ALAudioDevice", "setOutputVolume", 10), ("ALAudioDevice", "setOutputVolume", 60))
    assert line.startswith("FAIL robot") and "volume 10%" in line and "fix: raise the robot's volume" in line
    line = failing(("NaoTrainerStandIn", "set_battery", 12), ("NaoTrainerStandIn", "set_battery", 85))
    assert line.startswith("FAIL robot") and "battery 12%" in line and "fix: charge the robot" in line


def test_an_unreachable_robot_fails_with_exit_3_and_no_traceback(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    res = check("--config", study(tmp_path, "{mode: \"off\"}"), "--robot", f"tcp://127.0.0.1:{port}",
                "--out", str(tmp_path / "s"))
    assert res.returncode == 3 and "Traceback" not in res.stderr
    line = res.stdout.strip().splitlines()[1]
    assert line.startswith("FAIL robot") and "connection refused" in line and "\n" not in line


def _uid() -> str:
    return f"MuseCheck-{uuid.uuid4().hex[:10]}"


@pytest.mark.slow
def test_eeg_contact_is_judged_per_channel_on_a_real_lsl_stream(standin, tmp_path):
    sid = _uid()
    muse = SimulatedMuse.start(np.random.default_rng(1), source_id=sid)
    try:
        muse.set_fault(1, "flat")  # AF7 off the skin
        eeg = (f"{{mode: lsl, source_id: {sid}, required: true, allow_simulated: true, "
               "processing: {window_s: 0.5, hop_s: 0.25}}")
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"),
                    "--seconds", "1.5")
        assert res.returncode == 0, res.stdout + res.stderr
        line = res.stdout.strip().splitlines()[2]
        assert line.startswith("OK   eeg") and f"source_id {sid!r}" in line and "256 Hz" in line
        assert "AF7 0% (flat)" in line and "TP9 100%" in line and "AF7: the electrode is off the skin" in line
        for ch in (0, 2):
            muse.set_fault(ch, "saturated")
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"),
                    "--seconds", "1.5")
        assert res.returncode == 4, res.stdout
        line = res.stdout.strip().splitlines()[2]
        assert line.startswith("FAIL eeg") and "fewer than 2 clean channels" in line and "fix: TP9:" in line
        res = check("--config", study(tmp_path, eeg.replace("required: true", "required: false")), "--robot", standin,
                    "--out", str(tmp_path / "s"), "--seconds", "1.5")
        assert res.returncode == 0 and "(not required: the session runs without it)" in res.stdout
    finally:
        muse.stop()


def test_a_simulated_stream_fails_for_a_persons_session_unless_the_pilot_flag_allows_it(standin, tmp_path):
    """Issue 17: `simulate-muse` passed for the participant's headband (OK eeg ... contact 100%)."""
    sid = _uid()
    muse = SimulatedMuse.start(np.random.default_rng(1), source_id=sid)
    try:
        eeg = f"{{mode: lsl, source_id: {sid}, required: false, processing: {{window_s: 0.5, hop_s: 0.25}}}}"
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"), "--seconds", "1")
        assert res.returncode == 4, res.stdout + res.stderr
        line = res.stdout.strip().splitlines()[2]
        assert line.startswith("FAIL eeg") and "is simulated" in line and "--allow-simulated-eeg" in line
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"), "--seconds", "1",
                    "--allow-simulated-eeg")
        assert res.returncode == 0, res.stdout + res.stderr
        line = res.stdout.strip().splitlines()[2]
        assert line.startswith("OK   eeg") and f"(simulated, source_id {sid!r}" in line
    finally:
        muse.stop()


def test_several_matching_streams_with_nothing_pinned_fail_and_say_how_to_pin(standin, tmp_path):
    name = _uid()
    sids = [_uid(), _uid()]
    muses = [SimulatedMuse.start(np.random.default_rng(i), name=name, source_id=sid) for i, sid in enumerate(sids)]
    try:
        eeg = f"{{mode: lsl, stream_name: {name}, required: true, allow_simulated: true}}"
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"), "--seconds", "1")
        assert res.returncode == 4, res.stdout + res.stderr
        line = res.stdout.strip().splitlines()[2]
        assert line.startswith("FAIL eeg") and "2 EEG streams match" in line and all(s in line for s in sids)
        assert "fix: pin one: eeg.source_id" in line and "--eeg-source-id" in line
        res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"), "--seconds", "1",
                    "--eeg-source-id", sids[1])
        assert res.returncode == 0 and sids[1] in res.stdout.strip().splitlines()[2], res.stdout
    finally:
        for m in muses:
            m.stop()


def test_a_missing_required_stream_fails_with_exit_4(standin, tmp_path):
    eeg = f"{{mode: lsl, source_id: {_uid()}, required: true, processing: {{resolve_timeout_s: 1}}}}"
    res = check("--config", study(tmp_path, eeg), "--robot", standin, "--out", str(tmp_path / "s"))
    assert res.returncode == 4
    line = res.stdout.strip().splitlines()[2]
    assert line.startswith("FAIL eeg  ") and "no EEG stream" in line and "fix: start the headband bridge" in line


def test_disk_space_and_exit_codes(tmp_path):
    ok = check_disk(tmp_path / "not" / "yet")
    assert ok.ok and "GB free" in ok.line()
    full = check_disk(tmp_path, min_free_mb=1e12)
    assert not full.ok and full.exit_code == 2 and "fix: free some space" in full.line()
    optional = CheckResult("eeg", False, "no stream", "start it", required=False)
    assert exit_code([ok, optional]) == 0
    assert exit_code([ok, optional, CheckResult("robot", False, "gone"), full]) == 3


def test_every_folder_the_session_writes_is_tried_not_inferred(tmp_path, monkeypatch):
    import errno
    import tempfile

    (tmp_path / "blocker").write_text("a file where the participant's folder would go")
    blocked = check_disk(tmp_path / "out", write_dirs=(tmp_path / "blocker" / "P1",))
    assert not blocked.ok and blocked.exit_code == 2
    assert f"{tmp_path / 'blocker' / 'P1'}: cannot write there ({tmp_path / 'blocker'} is a file, not a folder)" in blocked.line()

    def read_only(*args, **kw):  # a read-only file system (root passes permission bits: the write is tried)
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    ro = check_disk(tmp_path / "out")
    assert not ro.ok and "cannot write there (the file system is read-only)" in ro.line()


def test_check_projects_the_battery_and_the_joint_heat_over_the_session_length(tmp_path):
    """`nao-trainer check` against a stand-in over qi: the robot line says whether the battery and the legs last a
    session of the study's length (both estimates: the battery from its charge, the warmest leg joint projected
    linearly at robot.model_settings.heat_c_per_min to hot_joint_c), and fails (exit 3) with the fix when not."""
    from nao_trainer.robot.standin.client import StandInClient

    # the stand-in in a process of its own (a qi server closed in the test's own process crashed it once in
    # two suites run side by side: SIGSEGV in qi's Session.close), acted on through its control service
    proc, url = spawn_standin(speed=50)

    def robot_line(minutes: int) -> tuple[int, str]:
        path = tmp_path / "study.yaml"
        path.write_text("study: {name: check}\nanswers: {input: tactile}\neeg: {mode: \"off\"}\n"
                        f"session: {{max_duration_s: {minutes * 60}}}\n")
        res = check("--config", str(path), "--robot", url, "--out", str(tmp_path / "s"))
        assert "Traceback" not in res.stderr
        (line,) = [ln for ln in res.stdout.splitlines() if ln.split()[1:2] == ["robot"]]
        return res.returncode, line

    control = None
    try:
        control = StandInClient.connect(url)
        control.set_battery(100)
        # a cool robot (35 °C) and a 50-minute session: the battery lasts, the legs would not (a short session's
        # OK line: test_a_ready_robot_passes_and_a_quiet_muted_or_flat_one_fails_with_the_fix)
        code, line = robot_line(50)
        assert code == 3 and line.startswith("FAIL robot"), line
        assert "LHipPitch 35 °C now, ~85 °C after ~50 min standing" in line
        assert "fix: LHipPitch would be hot after ~35 min of standing: let the robot cool" in line
        # a warm knee (58 °C, its status still normal) and a 15-minute session
        control.warm("RKneePitch", 58.0)
        code, line = robot_line(15)
        assert code == 3 and "RKneePitch 58 °C now, ~73 °C after ~15 min standing" in line, line
        assert "fix: RKneePitch would be hot after ~12 min of standing" in line
        # a cool knee again, a low battery (above the 30 % floor, below what 30 minutes need)
        control.warm("RKneePitch", 35.0)
        control.set_battery(35)
        code, line = robot_line(30)
        assert code == 3 and "battery 35% lasts ~21 min, the session needs ~30 min" in line, line
        assert "~65 °C after ~30 min standing" in line and "fix: charge the robot first (about 50% is needed)" in line
    finally:
        if control is not None:
            control.close()
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
