"""Robot link figures over real qi on 127.0.0.1: connect, call round trip, press latency, reconnect.

Press latency matters because reaction times are stamped when the callback runs: it is the
delay between a head-button event on the robot side and ``callback(letter, t)`` in the session.
Run: ``python benchmarks/bench_robot.py`` (about 10 s).
"""
from __future__ import annotations

import os
import signal
import statistics
import sys
import threading
import time

os.environ.setdefault("QI_LOG_LEVEL", "silent")

from nao_trainer.errors import RobotUnavailable  # noqa: E402
from nao_trainer.robot.naoqi import NaoqiRobot  # noqa: E402
from nao_trainer.robot.standin import StandIn, StandInClient, spawn_standin  # noqa: E402


def _ms(values: list[float]) -> str:
    v = sorted(x * 1000 for x in values)
    p95 = v[min(len(v) - 1, int(0.95 * len(v)))]
    return f"median {statistics.median(v):7.2f} ms   p95 {p95:7.2f} ms   max {v[-1]:7.2f} ms   (n={len(v)})"


def bench_connect(url: str, n: int = 20) -> None:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        robot = NaoqiRobot.connect(url, 3.0)
        times.append(time.perf_counter() - t0)
        robot.close()
    print(f"connect            {_ms(times)}")


def bench_round_trip(robot: NaoqiRobot, n: int = 300) -> None:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        robot.set_eye_leds(0x000000, 0.0)  # an instant fadeRGB: pure call overhead
        times.append(time.perf_counter() - t0)
    print(f"call round trip    {_ms(times)}")


def bench_press_latency(robot: NaoqiRobot, url: str, n: int = 100) -> None:
    arrived = threading.Event()
    stamp: list[float] = []

    def callback(letter: str, t: float) -> None:
        stamp.append(t)
        arrived.set()

    robot.subscribe_buttons(callback)
    memory = robot._service("ALMemory")
    times = []
    try:
        for i in range(n):
            arrived.clear()
            key = ("FrontTactilTouched", "MiddleTactilTouched", "RearTactilTouched")[i % 3]
            t0 = time.monotonic()
            memory.raiseEvent(key, 1.0, _async=True)
            if not arrived.wait(2.0):
                raise RuntimeError("a press did not arrive within 2 s")
            times.append(stamp[-1] - t0)
            memory.raiseEvent(key, 0.0)
    finally:
        robot.unsubscribe_buttons()
    print(f"press -> callback  {_ms(times)}")


def bench_reconnect(n: int = 5) -> None:
    proc, url = spawn_standin(speed=100)
    port = int(url.rsplit(":", 1)[1])
    robot = NaoqiRobot.connect(url, 3.0)
    robot.subscribe_buttons(lambda letter, t: None)
    times = []
    try:
        for _ in range(n):
            proc.kill()
            proc.wait()
            proc, _ = spawn_standin(port=port, speed=100)
            t0 = time.perf_counter()
            robot.reconnect(3.0)  # includes re-subscribing the three buttons
            times.append(time.perf_counter() - t0)
            robot.say("ok")
    finally:
        robot.close()
        proc.send_signal(signal.SIGINT)
        proc.wait()
    print(f"reconnect+resub    {_ms(times)}")


def bench_silent_deadline(deadline_s: float = 1.0) -> None:
    import socket

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        t0 = time.perf_counter()
        try:
            NaoqiRobot.connect(f"tcp://127.0.0.1:{server.getsockname()[1]}", deadline_s)
        except RobotUnavailable:
            pass
        print(f"silent port: gave up after {time.perf_counter() - t0:.3f} s (deadline {deadline_s:g} s)")


def main() -> int:
    with StandIn.start(speed=1000.0) as standin:
        bench_connect(standin.url)
        robot = NaoqiRobot.connect(standin.url, 3.0, debounce_s=0.0)  # presses here come faster than 0.15 s
        try:
            bench_round_trip(robot)
            bench_press_latency(robot, standin.url)
        finally:
            robot.close()
        with StandInClient.connect(standin.url) as remote:
            t0 = time.perf_counter()
            remote.transcript()
            print(f"transcript of {len(standin.transcript())} calls fetched in {1000 * (time.perf_counter() - t0):.1f} ms")
    bench_reconnect()
    bench_silent_deadline()
    return 0


if __name__ == "__main__":
    sys.exit(main())
