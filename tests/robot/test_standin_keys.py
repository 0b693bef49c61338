"""The stand-in from the command line (issue 29): head buttons from mock-robot's terminal (a, b, c) and from another
shell (`mock-robot press A|B|C --robot URL`), so hardware-check can be rehearsed with no robot."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import termios
import time
import uuid
from pathlib import Path

import pytest

from nao_trainer.robot.standin.keys import HELP, ButtonKeys

ROOT = Path(__file__).resolve().parents[2]


def wait_for(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    pytest.fail(f"timed out after {timeout} s waiting for {what}")


def test_keys_press_head_buttons_and_the_terminal_is_restored(tmp_path):
    master, slave = os.openpty()
    pressed: list[str] = []
    try:
        before = termios.tcgetattr(slave)
        out = open(tmp_path / "out.txt", "w+")
        reader = ButtonKeys.start_if_terminal(pressed.append, out, fd=slave)
        assert reader is not None and not termios.tcgetattr(slave)[3] & termios.ICANON
        os.write(master, b"axBc")
        wait_for(lambda: len(pressed) == 3, 5, "three presses")
        reader.close()
        assert pressed == ["A", "B", "C"] and termios.tcgetattr(slave) == before
        out.seek(0)
        text = out.read()
        assert HELP in text and "[b] middle head button (B) pressed" in text
    finally:
        os.close(master)
        os.close(slave)


def test_no_keys_without_a_terminal():
    r, w = os.pipe()
    try:
        assert ButtonKeys.start_if_terminal(lambda letter: None, None, fd=r) is None
    finally:
        os.close(r)
        os.close(w)


def test_press_without_a_stand_in_is_one_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), QI_LOG_LEVEL="silent")
    done = subprocess.run([sys.executable, "-m", "nao_trainer", "mock-robot", "press", "a", "--robot",
                           "tcp://127.0.0.1:9"], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 3 and len(done.stderr.strip().splitlines()) == 1
    assert "is `nao-trainer mock-robot` running there?" in done.stderr


def test_hardware_check_passes_on_the_stand_in_with_keys_and_press(tmp_path):
    tmux = shutil.which("tmux")
    if tmux is None:
        pytest.skip("tmux is not installed (.ci/run installs it): the stand-in's terminal keys were not tested")
    sock = f"nao-standin-{uuid.uuid4().hex[:8]}"
    env = dict(os.environ, PYTHONPATH=str(ROOT), QI_LOG_LEVEL="silent")
    serve = f"cd {ROOT} && PYTHONPATH={ROOT} QI_LOG_LEVEL=silent {sys.executable} -m nao_trainer mock-robot " \
            "--listen tcp://127.0.0.1:0 --speed 20; sleep 30"
    subprocess.run([tmux, "-L", sock, "new-session", "-d", "-s", "r", "-x", "200", "-y", "40", serve], check=True)

    def screen() -> str:
        return subprocess.run([tmux, "-L", sock, "capture-pane", "-p", "-t", "r", "-S", "-100"],
                              capture_output=True, text=True).stdout

    check = None
    try:
        url = wait_for(lambda: (m := re.search(r"listening on (tcp://127\.0\.0\.1:\d+)", screen())) and m.group(1),
                       60, "the stand-in's ready line")
        wait_for(lambda: HELP.split(":")[0] in screen(), 30, "the keys' help line")
        log = open(tmp_path / "check.txt", "w+")
        check = subprocess.Popen([sys.executable, "-m", "nao_trainer", "hardware-check", "--robot", url,
                                  "--timeout", "120"], stdout=log, stderr=subprocess.STDOUT, text=True, env=env)

        def asked(text: str, n: int = 1) -> bool:
            log.seek(0)
            return log.read().count(text) >= n

        wait_for(lambda: asked("touch the FRONT head button if you heard"), 120, "the confirmation request")
        subprocess.run([tmux, "-L", sock, "send-keys", "-t", "r", "a"], check=True)  # heard: front, on its terminal
        wait_for(lambda: asked("touch the FRONT head button (A)"), 120, "the front button request")
        subprocess.run([tmux, "-L", sock, "send-keys", "-t", "r", "a"], check=True)
        wait_for(lambda: asked("touch the MIDDLE head button (B)"), 120, "the middle button request")
        press = subprocess.run([sys.executable, "-m", "nao_trainer", "mock-robot", "press", "B", "--robot", url],
                               capture_output=True, text=True, env=env, timeout=120)  # from another shell
        assert press.returncode == 0 and "pressed the middle head button (B" in press.stdout, press.stderr
        wait_for(lambda: asked("touch the REAR head button (C)"), 120, "the rear button request")
        subprocess.run([tmux, "-L", sock, "send-keys", "-t", "r", "c"], check=True)
        assert check.wait(timeout=120) == 0
        pane = screen()
    finally:
        if check is not None and check.poll() is None:
            check.kill()
            check.wait()
        subprocess.run([tmux, "-L", sock, "kill-server"], capture_output=True)
    log.seek(0)
    text = log.read()
    for item in ("heard", "button A", "button B", "button C"):
        assert re.search(rf"PASS\s+{item}", text), (item, text)
    assert "[a] front head button (A) pressed" in pane and "[c] rear head button (C) pressed" in pane
