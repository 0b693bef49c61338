"""A simulated participant: answers turns the way a user model says a person would.

It draws the outcome of each turn from a ``core.simulation.UserSimulator`` for the turn's MDP
state, builds the response (the sequence, or a plausible mistake: one letter changed, two
letters swapped, one letter forgotten), draws reaction and completion times, and tells a
simulated Muse which engagement to show. When the robot is the NAO stand-in, the presses go
through the robot's head buttons (the stand-in's control service over qi), so the session's
tactile path is exercised end to end; otherwise the answer is handed back directly.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from nao_trainer.answers.inputs import TactileAnswers
from nao_trainer.core import task
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import RobotUnavailable
from nao_trainer.tasks.sequence.rules import MISTAKES, make_mistake  # noqa: F401 - this module's API
from nao_trainer.ports import Answer, EngagementMonitor, Intention, NullMonitor, Press, RobotConnectionLost, TurnContext

@dataclass(frozen=True)
class Plan:
    """What the participant will do in one answer window (times in session seconds from the beep)."""

    success: bool
    response: tuple[str, ...]
    times: tuple[float, ...]
    mistake: str = ""


class SimulatedParticipant:
    """``ports.AnswerSource`` driven by a user simulator.

    ``press`` delivers one letter to the robot's head buttons and ``inner`` (a ``TactileAnswers``)
    collects them; with ``press=None`` the answer is returned directly. ``speed`` divides every
    waiting time; ``min_gap_s`` (session seconds, above the debounce interval) keeps presses of a
    fast simulated hand apart. The gap is kept where the debounce applies, at the receiving end:
    each press waits until the previous one has arrived, plus the gap, so a late press (a slow
    qi call, a busy core) never pulls the next one under the debounce interval.
    """

    #: Longest wait for a press to arrive before the next one goes anyway (real seconds): long enough for a
    #: qi callback on a loaded machine, else the next press may reach the debounce with it and be dropped.
    ARRIVAL_TIMEOUT_S = 2.0

    def __init__(self, simulator: UserSimulator, rng: np.random.Generator, speed: float = 1.0,
                 monitor: EngagementMonitor | None = None, press: Callable[[str], object] | None = None,
                 inner: TactileAnswers | None = None, min_gap_s: float = 0.2, task: Any = None) -> None:
        if (press is None) != (inner is None):
            raise ValueError("press and inner go together: presses need an answer source that receives them")
        self.simulator = simulator
        self.rng = rng
        self.speed = float(speed)
        self.monitor = monitor or NullMonitor()
        self.press = press
        self.inner = inner
        self.min_gap_s = float(min_gap_s)
        #: A task with its own simulated participant (``simulated_answer``, e.g. n-back's signal-detection observer).
        self.own_answer = getattr(task, "simulated_answer", None)
        self.plan: Plan | None = None
        self._opened = 0.0
        self._presser: threading.Thread | None = None
        self._press_error: str | None = None  # a press that failed (robot gone): collect() reports it
        self._generation = 0
        self._watch: Callable[[Press], None] | None = None

    def watch(self, callback: Callable[[Press], None]) -> None:
        """Presses go through ``inner`` when there is one (it reports them), else are reported at collect."""
        if self.inner is not None:
            self.inner.watch(callback)
        self._watch = callback

    def prepare(self, context: TurnContext) -> None:
        """Decide the turn's outcome, response and timing; set the simulated Muse's target."""
        if self.own_answer is not None and context.trial is not None:
            rt, _ = self.simulator.sample_times(context.trial.level, self.rng)
            success, response, times, mistake = self.own_answer(context.trial, self.rng, min(rt, 1.5))
            self.plan = Plan(success, response, times, mistake)
            self.monitor.set_target(self.simulator.engagement_of(context.state, success))
            return
        success = self.simulator.sample_success(context.state, self.rng)
        response, mistake = (context.sequence, "") if success else make_mistake(context.sequence, self.rng)
        rt, ct = self.simulator.sample_times(task.level_of(context.length), self.rng)
        n = len(response)
        times = np.linspace(rt, max(ct, rt + self.min_gap_s * (n - 1)), n) if n else np.array([])
        self.plan = Plan(success, tuple(response), tuple(float(t) for t in times), mistake)
        self.monitor.set_target(self.simulator.engagement_of(context.state, success))

    def intended(self) -> Intention | None:
        """The plan of the prepared turn (recorded as ``simulated_plan``)."""
        p = self.plan
        return None if p is None else Intention(p.success, p.response, p.mistake)

    def open_window(self) -> None:
        self._opened = time.monotonic()
        self._generation += 1
        self._press_error = None
        if self.inner is not None:
            self.inner.open_window()
            self._presser = threading.Thread(target=self._press_all, args=(self.plan, self._opened, self._generation),
                                             name="simulated-presses", daemon=True)
            self._presser.start()

    def _press_all(self, plan: Plan, opened: float, generation: int) -> None:
        assert self.press is not None and self.inner is not None
        gap = self.min_gap_s / self.speed
        arrived: float | None = None  # when the previous press reached the answer window
        for i, (letter, t) in enumerate(zip(plan.response, plan.times)):
            due = opened + t / self.speed
            if arrived is not None:
                due = max(due, arrived + gap)
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if generation != self._generation:
                return  # the turn was abandoned (robot lost): never press into a later window
            try:
                self.press(letter)
            except Exception as exc:  # noqa: BLE001 - robot gone: the session sees it on its next call
                self._press_error = str(exc)
                return
            if i + 1 < len(plan.response):
                arrived = self.inner.window.wait_for_press(i + 1, self.ARRIVAL_TIMEOUT_S) or time.monotonic()

    def collect(self, n_expected: int, timeout_s: float) -> Answer:
        if self.plan is None:
            raise ValueError("collect() before prepare()")
        if self.inner is not None:
            answer = self.inner.collect(n_expected, timeout_s)
            if self._presser is not None:
                self._presser.join(timeout=max(0.0, self._opened + timeout_s - time.monotonic()) + 1.0)
            error, self._press_error = self._press_error, None
            if error is not None:
                raise RobotConnectionLost(f"a head-button press failed during the answer window: {error}")
            return answer
        presses = tuple(Press(key=l, letter=l, t=t / self.speed)
                        for l, t in zip(self.plan.response, self.plan.times) if t / self.speed <= timeout_s)
        timed_out = len(presses) < n_expected
        end = timeout_s if timed_out else presses[-1].t if presses else 0.0
        delay = self._opened + end - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if self._watch is not None:
            for p in presses:
                self._watch(p)
        return Answer(presses=presses, timed_out=timed_out)

    def abandon(self) -> None:
        """The turn was interrupted: stop pressing (presses must not land in a later window)."""
        self._generation += 1

    def close(self) -> None:
        self._generation += 1
        if self.inner is not None:
            self.inner.close()


class StandInButtons:
    """Presses the NAO stand-in's head buttons through its control service, over its own qi session.

    A separate client, like a finger (``robot.standin.StandInClient``): after a failure (the
    stand-in was restarted) it reconnects on the next press.
    """

    def __init__(self, url: str, deadline_s: float = 5.0) -> None:
        self.url = url
        self.deadline_s = deadline_s
        self._client = None
        self._lock = threading.Lock()

    def __call__(self, letter: str) -> None:
        from nao_trainer.robot.standin import StandInClient

        with self._lock:
            for attempt in (1, 2):  # a stale connection (the stand-in restarted) gets one fresh try
                try:
                    if self._client is None:
                        self._client = StandInClient.connect(self.url, self.deadline_s)
                    self._client.press(letter)
                    return
                except (RuntimeError, ConnectionError, RobotUnavailable):
                    self._drop()
                    if attempt == 2:
                        raise

    def _drop(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except RuntimeError:
                pass
        self._client = None

    def close(self) -> None:
        with self._lock:
            self._drop()

    @classmethod
    def probe(cls, url: str, deadline_s: float = 3.0) -> "StandInButtons | None":
        """A presser when ``url`` serves the stand-in's control service, else None (a real NAO)."""
        from nao_trainer.robot.standin import StandInClient

        buttons = cls(url, deadline_s)
        try:
            buttons._client = StandInClient.connect(url, deadline_s)
        except RobotUnavailable:
            return None
        return buttons
