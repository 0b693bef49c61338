"""The link watchdog with an injected ping (no network): what it concludes, and that leaving it waits for a ping."""
from __future__ import annotations

import threading

import pytest

from nao_trainer.ports import NullLinkWatch, RobotCallFailed, RobotConnectionLost, watch_link
from nao_trainer.robot.watchdog import LinkWatchdog


class Pings:
    """Answers ``ok`` pings, then fails the way a silent link does (or refuses, still alive)."""

    def __init__(self, ok: int, then: type[Exception] | None) -> None:
        self.ok, self.then = ok, then
        self.calls = 0
        self.done = threading.Event()

    def __call__(self, deadline_s: float) -> float:
        self.calls += 1
        if self.calls > self.ok and self.then is not None:
            self.done.set()
            raise self.then(f"ALMemory.getData did not answer within {deadline_s:g} s")
        if self.calls >= self.ok and self.then is not RobotConnectionLost:
            self.done.set()
        return 0.001


def test_a_ping_without_answer_marks_the_link_lost():
    pings = Pings(ok=2, then=RobotConnectionLost)
    with LinkWatchdog(pings, interval_s=0.01, deadline_s=0.5) as watch:
        assert pings.done.wait(10)
    assert watch.lost is not None and "did not answer within 0.5 s" in watch.lost
    assert watch.pings == 2


def test_an_answering_link_is_not_lost_and_a_refusal_is_an_answer():
    for then in (None, RobotCallFailed):
        pings = Pings(ok=3, then=then)
        with LinkWatchdog(pings, interval_s=0.01, deadline_s=0.5) as watch:
            assert pings.done.wait(10)
        assert watch.lost is None


def test_leaving_waits_for_the_ping_in_flight():
    started, release = threading.Event(), threading.Event()

    def slow_ping(deadline_s: float) -> float:
        started.set()
        release.wait(10)
        raise RobotConnectionLost("no answer")

    watch = LinkWatchdog(slow_ping, interval_s=1.0, deadline_s=5.0)
    with watch:
        assert started.wait(10)
        threading.Timer(0.05, release.set).start()
    assert watch.lost == "no answer"  # seen although the window had ended while the ping was out


def test_robots_without_a_link_get_a_null_watch():
    assert isinstance(watch_link(object()), NullLinkWatch)
    with pytest.raises(ValueError):
        LinkWatchdog(lambda s: 0.0, interval_s=0)
