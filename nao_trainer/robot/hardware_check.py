"""The hardware check an operator runs in front of the robot before each participant.

The robot says a test sentence, the letters A, B and C and beeps; the operator touches the front
button to confirm they heard all of it; then the robot asks for each head button in turn and the
check reports which button arrived and after how long. It shows the system volume, mute, battery,
Autonomous Life and NAOqi version, and ends with one PASS or FAIL line per item. Autonomous Life is
set to the study's state for the check (a hand held on the head would otherwise put NAO to sleep)
and restored at the end; the motors are not touched.
"""
from __future__ import annotations

import queue
import time
from dataclasses import dataclass
from typing import Any, Callable, TextIO

from nao_trainer.errors import RobotUnavailable
from nao_trainer.ports import BUTTON_LETTERS, RobotCallFailed, RobotConnectionLost
from nao_trainer.robot.lifecycle import TaskLife

SENTENCE = "Hello. This is the hardware check. Please listen carefully."
CONFIRM = "If you heard the letters and the beep, touch my front head button."
ASK = "Touch my {} head button."
NAMES = {"A": "front", "B": "middle", "C": "rear"}
MIN_VOLUME, MIN_BATTERY = 30, 30


@dataclass(frozen=True)
class Item:
    """One line of the verdict."""

    name: str
    ok: bool
    detail: str

    def line(self) -> str:
        return f"{'PASS' if self.ok else 'FAIL'}  {self.name:<14} {self.detail}"


class _Presses:
    """Head-button presses as they arrive (qi threads), read by the check in order."""

    def __init__(self) -> None:
        self._queue: queue.Queue[tuple[str, float]] = queue.Queue()

    def __call__(self, letter: str, t: float) -> None:
        self._queue.put((letter, t))

    def drain(self) -> None:
        while not self._queue.empty():
            self._queue.get_nowait()

    def next(self, timeout_s: float) -> tuple[str, float] | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None


def run_hardware_check(robot: Any, out: TextIO, press_timeout_s: float = 20.0, life_state: str = "disabled",
                       min_volume: int = MIN_VOLUME, min_battery: int = MIN_BATTERY,
                       clock: Callable[[], float] = time.monotonic) -> list[Item]:
    """Run every item against a connected ``NaoqiRobot``; print progress to ``out``; return the verdict."""
    items: list[Item] = []
    life = TaskLife(robot, life_state, rest_at_end=False, wake=False)
    presses = _Presses()
    try:
        status = life.enter()
        items += _status_items(status, min_volume, min_battery)
        robot.subscribe_buttons(presses)
        items.append(_sound(robot, out))
        items.append(_confirm(robot, presses, out, press_timeout_s, clock))
        for letter in BUTTON_LETTERS.values():
            items.append(_button(robot, presses, letter, out, press_timeout_s, clock))
        items.append(_link(robot))
    except (RobotConnectionLost, RobotCallFailed, RobotUnavailable) as exc:
        items.append(Item("robot", False, f"{exc}"))
    finally:
        try:
            robot.unsubscribe_buttons()
        finally:
            life.leave()
    return items


def _status_items(status: Any, min_volume: int, min_battery: int) -> list[Item]:
    vol = status.output_volume
    return [
        Item("robot", True, f"{status.name or 'unknown name'}, NAOqi {status.naoqi_version or 'unknown'}"),
        Item("volume", vol is not None and vol >= min_volume,
             f"{'unknown' if vol is None else f'{vol}%'} (ALAudioDevice; at least {min_volume}%)"),
        Item("mute", status.muted is False, "muted: unmute the robot" if status.muted else
             "not muted" if status.muted is False else "unknown (no ALAudioDevice)"),
        Item("battery", status.battery is not None and status.battery >= min_battery,
             f"{'unknown' if status.battery is None else f'{status.battery}%'} (at least {min_battery}%)"),
        Item("life", True, f"Autonomous Life {status.autonomous_life or 'unknown'}"
             + (f"; an earlier session did not restore it (found {status.left_by_earlier_session!r})"
                if status.left_by_earlier_session else "")),
    ]


def _sound(robot: Any, out: TextIO) -> Item:
    print("the robot speaks a sentence, the letters A, B, C, then beeps ...", file=out, flush=True)
    robot.say(SENTENCE)
    for letter in "ABC":
        robot.say(letter)
    timing = robot.beep(880, 0.3, 0.5)
    rtt = getattr(timing, "rtt_s", None)
    return Item("speech+beep", True, "said and played" + (f" (round trip {rtt * 1000:.1f} ms)" if rtt else ""))


def _confirm(robot: Any, presses: _Presses, out: TextIO, timeout_s: float, clock: Callable[[], float]) -> Item:
    print("touch the FRONT head button if you heard the sentence, the letters A, B, C and the beep", file=out,
          flush=True)
    presses.drain()
    asked = clock()
    robot.say(CONFIRM)
    got = presses.next(timeout_s)
    if got is None:
        return Item("heard", False, f"no confirmation within {timeout_s:g} s: check the volume and the speaker")
    return Item("heard", got[0] == "A", "operator confirmed" if got[0] == "A"
                else f"{NAMES[got[0]]} button touched instead of front ({got[1] - asked:.2f} s)")


def _button(robot: Any, presses: _Presses, letter: str, out: TextIO, timeout_s: float,
            clock: Callable[[], float]) -> Item:
    name = NAMES[letter]
    print(f"touch the {name.upper()} head button ({letter}) ...", file=out, flush=True)
    presses.drain()
    asked = clock()  # a press may come while the robot still speaks: count from the start of the request
    robot.say(ASK.format(name))
    got = presses.next(timeout_s)
    if got is None:
        return Item(f"button {letter}", False, f"no press of the {name} button within {timeout_s:g} s")
    pressed, t = got
    after = f"{t - asked:.2f} s after the request began"
    print(f"  pressed: {NAMES[pressed]} ({pressed}), {after}", file=out, flush=True)
    if pressed != letter:
        return Item(f"button {letter}", False, f"asked for {name}, got {NAMES[pressed]} ({after}): "
                    "check which sensor reacts, or that no other program holds the head buttons")
    return Item(f"button {letter}", True, f"{name} pressed, {after}")


def _link(robot: Any) -> Item:
    rtts = sorted(robot.ping(5.0) for _ in range(5))
    return Item("network", True, f"round trip median {rtts[2] * 1000:.1f} ms, max {rtts[-1] * 1000:.1f} ms")


def verdict(items: list[Item]) -> int:
    """0 when every item passed, else the robot's exit code."""
    return 0 if all(i.ok for i in items) else RobotUnavailable.exit_code
