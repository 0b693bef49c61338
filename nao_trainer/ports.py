"""The contracts between the session (orchestration) and its adapters.

The session depends only on these protocols; the qi robot, the answer inputs, the EEG monitor and
the policies implement them. Dependencies point inward: adapters import this module, never the
session.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

# ----------------------------------------------------------------------------------------------
# Robot
# ----------------------------------------------------------------------------------------------

#: Head buttons of the NAO mapped to the task's letters (front/middle/rear = A/B/C).
BUTTON_LETTERS: dict[str, str] = {
    "FrontTactilTouched": "A",
    "MiddleTactilTouched": "B",
    "RearTactilTouched": "C",
}


class RobotConnectionLost(Exception):
    """A call to the robot failed because the connection dropped; the session may reconnect."""


class RobotCallFailed(Exception):
    """The robot answered but refused a call (unknown posture, bad argument, service error).

    Not a lost connection: reconnecting would not help. The session logs a refused optional call
    (LEDs, posture) and ends with a robot error (exit 3) when a call the task needs is refused.
    """


def check_beep(frequency_hz: float, duration_s: float, gain: float) -> None:
    """ValueError for a beep no robot should play; every Robot checks ``beep`` arguments with this one rule."""
    if not 20 <= int(frequency_hz) <= 20000:
        raise ValueError(f"beep frequency must be 20..20000 Hz, got {frequency_hz!r}")
    if not 0.0 < float(duration_s) <= 60.0:
        raise ValueError(f"beep duration must be in (0, 60] seconds, got {duration_s!r}")
    if not 0.0 <= float(gain) <= 1.0:
        raise ValueError(f"beep gain must be in [0, 1], got {gain!r}")


@dataclass(frozen=True)
class BeepTiming:
    """When a beep sounded, as a robot that can tell returns it from ``beep`` (monotonic seconds).

    ``onset`` is the estimate reaction times are measured from: ``returned - duration - rtt/2``
    (assumes the call returns when the tone ends and the network is symmetric; see docs/how-to/robot.md).
    """

    start: float  # the call was sent
    returned: float  # its reply arrived
    rtt_s: float  # round trip of a cheap call just before
    duration_s: float
    onset: float


class LinkWatch(Protocol):
    """A watchdog on the link while nothing else talks to the robot (an answer window)."""

    lost: str | None  # why the link is considered lost, None while it answers

    def __enter__(self) -> "LinkWatch": ...

    def __exit__(self, *exc: object) -> None: ...


class NullLinkWatch:
    """A robot without a link to watch (the laptop, test fakes)."""

    lost: str | None = None

    def __enter__(self) -> "NullLinkWatch":
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def watch_link(robot: Any) -> LinkWatch:
    """The robot's link watchdog (``robot.watch_link()``) when it has one, else a ``NullLinkWatch``."""
    factory = getattr(robot, "watch_link", None)
    return factory() if callable(factory) else NullLinkWatch()


@runtime_checkable
class Robot(Protocol):
    """What the session asks of a robot. ``nao_trainer.robot.naoqi.NaoqiRobot`` implements it."""

    def say(self, text: str, animated: bool = False, mode: str = "contextual") -> None:
        """Speak ``text`` and return when done (ALTextToSpeech / ALAnimatedSpeech)."""

    def beep(self, frequency_hz: int, duration_s: float, gain: float = 0.5) -> "BeepTiming | None":
        """Play a sine beep (ALAudioPlayer.playSine); returns when it has been played, with its timing when known."""

    def set_eye_leds(self, rgb: int, duration_s: float) -> None:
        """Fade the eye LEDs to 0xRRGGBB (ALLeds.fadeRGB)."""

    def go_to_posture(self, name: str, speed: float) -> None:
        """Go to a predefined posture (ALRobotPosture.goToPosture)."""

    def stop_all(self) -> None:
        """Cut speech and sounds short (the operator interrupted the session)."""

    def subscribe_buttons(self, callback: Callable[[str, float], None]) -> None:
        """Call ``callback(letter, monotonic_time)`` on each head-button press (value 1.0)."""

    def unsubscribe_buttons(self) -> None:
        """Disconnect the button signals (required before exit, see platform notes)."""

    def reconnect(self, deadline_s: float) -> None:
        """Connect again after a loss, re-fetch services and re-subscribe the buttons."""

    def is_connected(self) -> bool:
        """Whether the connection is up (asked after an answer window, which does not talk to the robot)."""

    def close(self) -> None:
        """Disconnect signals and close the qi session."""


class RobotUpkeep(Protocol):
    """Keeps the robot as the task set it up (``robot.lifecycle.TaskLife``): Autonomous Life, motors."""

    def between_turns(self) -> list[str]:
        """Check and restore between two turns, and after a refused call; reports what it found and
        returns what it set back (empty: nothing was changed, or it could not be set back); never raises."""


    def hold_motors(self, why: str | None) -> None:
        """``why``: never wake the motors (the robot fell) until called again with None (the operator said it is up)."""


class NullUpkeep:
    """No robot to keep (the laptop plays it, or a test's fake)."""

    def between_turns(self) -> list[str]:
        return []

    def hold_motors(self, why: str | None) -> None:
        pass


#: What a robot's health watch reports (``HealthEvent.kind``).
HEALTH_KINDS: tuple[str, ...] = ("falling", "fallen", "hot", "battery_low", "chest", "chest_double", "diagnosis",
                                 "safeguard")


@dataclass(frozen=True)
class HealthEvent:
    """Something the robot reported about itself during a session (an ALMemory event, ``robot.health``).

    ``severity``: "info", "warning" or "critical"; ``part``: the joint or device named (heat), else "";
    ``at``: ``time.monotonic()`` when it arrived; ``value``: what the robot sent, JSON-ready."""

    kind: str
    severity: str
    detail: str
    part: str = ""
    at: float = 0.0
    value: Any = None


class RobotHealthWatch(Protocol):
    """The robot's health events since the last call (``robot.health.HealthWatch``); the session drains them
    between states, on its own thread. ``close`` stops watching."""

    def pending(self) -> list[HealthEvent]: ...

    def close(self) -> None: ...


class NullHealth:
    """Nothing watched (the laptop, test fakes)."""

    def pending(self) -> list[HealthEvent]:
        return []

    def close(self) -> None:
        pass


# ----------------------------------------------------------------------------------------------
# Answers
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TurnContext:
    """What an answer source may know of the turn (a simulated participant uses all of it)."""

    turn: int
    state: int  # turn-state index (core.mdp)
    length: int  # the trial's size (the sequence task: its letters)
    sequence: tuple[str, ...]  # the trial's stimuli
    trial: Any = None  # the task's ``tasks.base.Trial`` (a task's own simulated participant reads it)


@dataclass(frozen=True)
class Press:
    """One button press: its raw key/button and letter (None when invalid), seconds after the beep."""

    key: str
    letter: str | None
    t: float


@dataclass(frozen=True)
class Answer:
    """All presses of one answer window."""

    presses: tuple[Press, ...]
    timed_out: bool

    @property
    def response(self) -> tuple[str, ...]:
        return tuple(p.letter or "?" for p in self.presses)

    @property
    def reaction_time(self) -> float | None:
        return self.presses[0].t if self.presses else None

    @property
    def completion_time(self) -> float | None:
        return self.presses[-1].t if self.presses else None


@dataclass(frozen=True)
class Intention:
    """What a simulated participant decided to answer (recorded as ``simulated_plan``)."""

    success: bool
    response: tuple[str, ...]
    mistake: str


class AnswerSource(Protocol):
    """Collects a participant's answer. Presses before ``open_window`` are discarded."""

    def prepare(self, context: TurnContext) -> None:
        """Called before the robot speaks the sequence (a simulated participant decides here)."""

    def intended(self) -> Intention | None:
        """After ``prepare``: what a simulated participant will answer; None for a person."""

    def open_window(self) -> None:
        """Called right after the beep: the answer window opens, time 0 for press times."""

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        """Block until ``n_expected`` presses or the timeout; return what was pressed.

        Raises ``RobotConnectionLost`` when the answers could not reach the robot (a simulated press failed).
        """

    def abandon(self) -> None:
        """The turn was interrupted (robot lost): nothing of it may land in a later window. Often a no-op."""

    def watch(self, callback: Callable[[Press], None]) -> None:
        """Call ``callback(press)`` for every press of an answer window as it arrives (the console shows them)."""

    def close(self) -> None: ...


# ----------------------------------------------------------------------------------------------
# Engagement (EEG)
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PhaseEngagement:
    """Engagement over one phase of a turn, or why there is none."""

    engagement: float | None  # normalised to [0, 1]
    index: float | None  # raw E = beta / (alpha + theta)
    quality: float  # fraction of clean signal in the phase, 0..1
    reason: str = ""  # why engagement is None, empty otherwise
    series: np.ndarray | None = field(default=None, compare=False)  # per-window values
    lost_s: float = 0.0  # seconds of the phase without samples (the headband's stream had stopped)


class EngagementMonitor(Protocol):
    """Marks session phases and returns per-phase engagement. ``NullMonitor`` when EEG is off."""

    @property
    def records_eeg(self) -> bool:
        """Whether EEG is recorded at all (turns.csv leaves ``eeg_quality`` empty when not)."""

    def mark(self, event: str, turn: int | None = None) -> None:
        """Publish an event (session, turn, phase) on the LSL clock."""

    def begin_phase(self, phase: str, turn: int | None) -> None:
        """Start aggregating a phase: "baseline", "listening" or "answer"."""

    def end_phase(self) -> PhaseEngagement:
        """Stop aggregating and return the phase's engagement."""

    def set_target(self, engagement: float | None) -> None:
        """For a simulated Muse: the engagement its signal should show next (ignored otherwise)."""

    def live(self) -> dict | None:
        """The latest engagement index and per-channel contact quality (for a supervisor), None when EEG is off.

        Called from another thread: must only read."""

    def describe(self) -> str:
        """One line on the EEG source in use (stream name, source_id, rate, channels), or why there is none."""

    def close(self) -> None: ...


class NullMonitor:
    """EEG off: no markers, no engagement."""

    records_eeg = False

    def mark(self, event: str, turn: int | None = None) -> None:
        pass

    def begin_phase(self, phase: str, turn: int | None) -> None:
        pass

    def end_phase(self) -> PhaseEngagement:
        return PhaseEngagement(None, None, 0.0, "EEG off")

    def set_target(self, engagement: float | None) -> None:
        pass

    def live(self) -> dict | None:
        return None

    def describe(self) -> str:
        return "EEG off"

    def close(self) -> None:
        pass


# ----------------------------------------------------------------------------------------------
# Policies
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Transition:
    """One step of the MDP as the session saw it (see ``core.mdp``)."""

    state: int
    action: int
    score: int  # equation (1) of the turn played in next_state
    engagement: float | None  # that turn's normalised engagement, None when unavailable
    next_state: int
    done: bool


class Policy(Protocol):
    """Chooses the next action; learners also learn from ``observe``."""

    name: str

    def act(self, state: int, rng: np.random.Generator) -> int:
        """An allowed action for ``state`` (respecting ``core.mdp.action_mask``)."""

    def observe(self, transition: Transition) -> None:
        """Called after every turn with the transition that produced it."""

    def bind_state_dir(self, folder: Path) -> None:
        """The session folder exists: a learning policy without a state file of its own saves there."""

    def status(self) -> dict[str, Any]:
        """What the policy believes, for the record and the operator ({} when nothing to say).

        Keys the session uses when present: ``phase`` (of the turn just chosen, recorded in
        turns.csv), ``progress`` (a line after the turn's progress line), ``summary`` (the end of
        the session summary); the whole dict goes to events.jsonl after every turn.
        """

    def close(self) -> None:
        """Persist whatever must survive the session."""

    def probabilities(self, state: int) -> "np.ndarray | None":
        """P(a | state) the policy would choose with now (shown to a supervisor), None if unknown."""

    def guide(self, state: int, action: int) -> None:
        """A supervisor chose ``action`` in ``state`` (an override); a policy may come to prefer it."""

    def snapshot(self) -> dict | None:
        """The learning state as JSON-ready data (checkpointed after every turn), None when stateless."""

    def restore(self, data: dict | None) -> None:
        """Go back to a ``snapshot`` (a resumed session continues as if never interrupted)."""



# ----------------------------------------------------------------------------------------------
# Operator commands and observers
# ----------------------------------------------------------------------------------------------

#: What an operator can ask of a running session (terminal keys and the console share them).
COMMAND_KINDS: tuple[str, ...] = ("pause", "resume", "stop", "override", "repeat", "invalid", "note")


@dataclass(frozen=True)
class Command:
    """One operator command: ``kind`` (``COMMAND_KINDS``), its arguments, who sent it and when (ISO UTC)."""

    kind: str
    args: dict = field(default_factory=dict)
    source: str = "api"
    at: str = ""
    id: int = 0


class CommandQueue:
    """Thread-safe FIFO of operator commands; the session drains it at defined points only.

    Producers (a key reader thread, the console's server thread) ``submit``; the session thread
    ``drain``s between states and ``wait``s on it while paused. No command acts outside the session thread.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._items: list[Command] = []
        self._next_id = 1

    def submit(self, kind: str, args: dict | None = None, source: str = "api") -> Command:
        """Queue a command; ValueError for an unknown kind (the caller reports it)."""
        if kind not in COMMAND_KINDS:
            raise ValueError(f"unknown command {kind!r}; use one of {', '.join(COMMAND_KINDS)}")
        with self._cond:
            cmd = Command(kind, dict(args or {}), str(source),
                          datetime.now(timezone.utc).isoformat(timespec="milliseconds"), self._next_id)
            self._next_id += 1
            self._items.append(cmd)
            self._cond.notify_all()
        return cmd

    def drain(self) -> list[Command]:
        """Every queued command, oldest first (the queue is then empty)."""
        with self._cond:
            items, self._items = self._items, []
        return items

    def wait(self, timeout_s: float) -> bool:
        """Block until a command is queued or ``timeout_s`` passed; True when one is waiting."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            return bool(self._items)

    def take(self, kinds: tuple[str, ...]) -> list[Command]:
        """The queued commands of ``kinds``, oldest first, taken off the queue (the others stay queued)."""
        with self._cond:
            taken = [c for c in self._items if c.kind in kinds]
            self._items = [c for c in self._items if c.kind not in kinds]
        return taken

    def kinds(self) -> list[str]:
        """The kinds of the queued commands, oldest first (nothing is taken off the queue)."""
        with self._cond:
            return [c.kind for c in self._items]

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


class SessionObserver(Protocol):
    """Told what happens in a session as it happens (the console). ``notify`` must return at once."""

    def notify(self, kind: str, data: dict) -> None:
        """``kind``: session, state, turn_start, press, row, command, pause, summary (see docs/reference/console.md)."""


class NullObserver:
    """Nobody watching."""

    def notify(self, kind: str, data: dict) -> None:
        pass
