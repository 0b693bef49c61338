"""How the robot presents the session: speech with its behaviors, eye LEDs, postures, letters, beep.

``Stage`` is the only part of the session that calls the robot's presentation methods; the
engine says *what* happens (greet, announce level 2, speak "ABC", beep) and the stage says it
with the dialogue's words and the behaviors' colours and postures. ``Clock`` is the one place
that turns the session seconds of the configuration into wall seconds (``timing.speed``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from nao_trainer.ports import BeepTiming, Robot, RobotCallFailed, RobotConnectionLost
from nao_trainer.session.behaviors import Behaviors
from nao_trainer.session.config import TimingSection
from nao_trainer.session.dialogue import Dialogue
from nao_trainer.session.record import SessionRecorder


@dataclass
class Clock:
    """Session seconds <-> wall seconds at ``speed`` (a demo at speed 25 waits 1 s for 25 s)."""

    speed: float
    sleep: Callable[[float], None] = time.sleep
    now: Callable[[], float] = field(default=time.monotonic)

    def wall(self, session_s: float) -> float:
        """How long ``session_s`` session seconds last on the wall clock."""
        return float(session_s) / self.speed

    def session(self, wall_s: float) -> float:
        """A wall-clock duration in session seconds (reaction times are recorded in these)."""
        return float(wall_s) * self.speed

    def wait(self, session_s: float) -> None:
        """Wait ``session_s`` session seconds."""
        if session_s > 0:
            self.sleep(self.wall(session_s))

    def wait_until(self, wall_t: float) -> None:
        """Wait until the monotonic time ``wall_t`` (no-op when it has passed)."""
        remaining = wall_t - self.now()
        if remaining > 0:
            self.sleep(remaining)


class Stage:
    """The robot's presentation: every call the task needs goes through here.

    Eye colours and postures dress the session up: a robot that refuses one (``RobotCallFailed``)
    is logged, not fatal. Speech and the beep are needed, so their refusals propagate to the engine,
    like a lost connection (``RobotConnectionLost``) from any call.
    """

    def __init__(self, robot: Robot, dialogue: Dialogue, behaviors: Behaviors, rng: np.random.Generator,
                 recorder: SessionRecorder, clock: Clock, timing: TimingSection, posture_speed: float,
                 link_deadline_s: float) -> None:
        self.robot = robot
        self.dialogue = dialogue
        self.behaviors = behaviors
        self.rng = rng
        self.rec = recorder
        self.clock = clock
        self.timing = timing
        self.posture_speed = posture_speed
        self.link_deadline_s = link_deadline_s  # robot.link_deadline_s: a beep reply later than this is a frozen link
        #: Publishes an EEG/XDF marker (the engine sets it to the monitor's ``mark``); a stream task marks each stimulus.
        self.mark: Callable[[str, int | None], None] = lambda event, turn=None: None

    def _optional(self, what: str, call: Callable[[], Any]) -> None:
        try:
            call()
        except RobotCallFailed as exc:
            self.rec.event("robot_call_failed", what=what, error=str(exc))

    def leds(self, rgb: int) -> None:
        self._optional("leds", lambda: self.robot.set_eye_leds(rgb, self.clock.wall(self.behaviors.led_fade_s)))

    def posture(self, name: str) -> None:
        self._optional(f"posture {name}", lambda: self.robot.go_to_posture(name, self.posture_speed))

    def look(self, event: str) -> None:
        """Set the eye colour of ``event``."""
        self.leds(self.behaviors[event].leds)

    def say(self, event: str, behavior: str | None = None, rng: np.random.Generator | None = None, **fields: Any) -> str:
        """Say a dialogue line of ``event`` with the behavior of ``behavior`` (default: the event's own);
        the variant is drawn with ``rng`` (default: the session's generator)."""
        return self._say_as(behavior or event, event, self.dialogue.say(event, rng or self.rng, **fields))

    def feedback(self, kind: int, last_success: bool, level: int, turn: int) -> str:
        """Encouraging (kind 1) or challenging (2) feedback on the last outcome."""
        style = "encouraging" if kind == 1 else "challenging"
        text = self.dialogue.feedback(kind, last_success, self.rng, level=level)
        return self._say_as(style, f"{style}_{'success' if last_success else 'failure'}", text, turn=turn)

    def _say_as(self, behavior: str, what: str, text: str, **data: Any) -> str:
        b = self.behaviors[behavior]
        self.leds(b.leds)
        self.robot.say(text, b.animated, b.mode)
        self.rec.event("say", what=what, text=text, **data)
        return text

    def announce(self, level: int, length: int, look: bool = True, turn: int | None = None) -> None:
        """"Level N", plainly (no gestures), after the configured pause."""
        self.clock.wait(self.timing.pause_before_level_s)
        if look:
            self.look("level")
        text = self.dialogue.say("level", self.rng, level=level, length=length)
        self.robot.say(text, False, "disabled")
        self.rec.event("say", what="level", text=text, turn=turn)

    def letters(self, sequence: tuple[str, ...], turn: int | None = None) -> None:
        """Each letter as its own utterance, separated by the configured gap."""
        self.look("sequence")
        for i, letter in enumerate(sequence):
            if i:
                self.clock.wait(self.timing.letter_gap_s)
            self.robot.say(letter, False, "disabled")
            self.rec.event("say", what="letter", text=letter, turn=turn, index=i + 1)

    def stream(self, stimuli: tuple[str, ...], soa_s: float, onset: float, turn: int,
               targets: tuple[bool, ...] | None = None) -> list[float]:
        """Each stimulus on a fixed grid after the beep (stimulus i at (i + 1) x ``soa_s`` session seconds), each
        an event and an EEG/XDF marker; returns the actual onsets in wall seconds after the beep (a slow call
        shifts a later stimulus, never the grid)."""
        self.look("sequence")
        onsets: list[float] = []
        for i, letter in enumerate(stimuli):
            self.clock.wait_until(onset + self.clock.wall((i + 1) * soa_s))
            onsets.append(self.clock.now() - onset)
            self.mark(f"stimulus_{i + 1}", turn)
            self.robot.say(letter, False, "disabled")
            extra = {} if targets is None else {"target": bool(targets[i])}
            self.rec.event("say", what="stimulus", text=letter, turn=turn, index=i + 1, **extra)
        return onsets

    def beep(self, turn: int) -> float:
        """Beep (the answer window must be open already); returns the onset on the monotonic clock.

        The onset is the robot's estimate when it returns a ``BeepTiming`` (a NAO over qi), else the
        moment the call was made (the laptop, fakes). The beep is the one call of the window the link
        watchdog cannot watch: a reply more than ``link_deadline_s`` later than the tone and the round
        trip allow is a frozen link (``RobotConnectionLost``: the turn is replayed), since the window
        and the onset estimate are then off by the freeze (seen: 8 s, and the turn scored as a failure).
        """
        t = self.timing
        start = self.clock.now()
        timing = self.robot.beep(t.beep_hz, self.clock.wall(t.beep_s), t.beep_gain)
        if isinstance(timing, BeepTiming):
            self.rec.event("beep", turn=turn, rtt_ms=round(timing.rtt_s * 1000, 2),
                           call_ms=round((timing.returned - timing.start) * 1000, 2),
                           onset_after_call_ms=round((timing.onset - timing.start) * 1000, 2))
            late = timing.returned - timing.start - timing.duration_s - timing.rtt_s
            if late > self.link_deadline_s:
                raise RobotConnectionLost(f"the link to the robot froze during the beep: its reply came {late:.1f} s "
                                          f"late (robot.link_deadline_s is {self.link_deadline_s:g} s)")
            return timing.onset
        self.rec.event("beep", turn=turn)
        return start

    def goodbye(self, total: int, turns: int) -> None:
        """The closing words (without a number when the total is zero or negative), end posture, LEDs off."""
        self.say(self.dialogue.goodbye_event(total), behavior="goodbye", total=total, turns=turns)
        self.posture(self.behaviors.end_posture)
        self.leds(self.behaviors.leds_reset)

    def silence(self) -> None:
        """Cut speech short (the operator interrupted); a failure is logged."""
        try:
            self.robot.stop_all()
        except (RobotCallFailed, RobotConnectionLost) as exc:
            self.rec.event("robot_call_failed", what="stop speech", error=str(exc))

    def leave_safe(self) -> None:
        """Safe posture and LEDs reset, whatever happened; failures are logged, never raised."""
        leave_robot_safe(self.robot, self.behaviors, self.posture_speed, self.rec)


def leave_robot_safe(robot: Robot, behaviors: Behaviors, posture_speed: float,
                     recorder: SessionRecorder | None = None) -> None:
    """Safe posture and LEDs reset, whatever happened; failures are logged to ``recorder``, never raised."""
    def log(name: str, **data: Any) -> None:
        if recorder is not None:
            recorder.event(name, **data)

    if not robot.is_connected():
        log("safe_state_skipped", why="robot not connected")
        return
    for what, call in (
        ("posture", lambda: robot.go_to_posture(behaviors.safe_posture, posture_speed)),
        ("leds", lambda: robot.set_eye_leds(behaviors.leds_reset, 0.0)),
    ):
        try:
            call()
            log("safe_state", what=what)
        except Exception as exc:  # noqa: BLE001 - shutdown must go on (robot may be gone)
            log("safe_state_failed", what=what, error=str(exc))
