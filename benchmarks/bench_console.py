"""What the supervisor console costs the session per turn (issue 11: under 1 ms per turn).

Plays a session with the in-memory robot of the tests (no waits) while a real console serves it
to N connected viewers (Server-Sent Events read by client threads), and measures the time the
session thread spends in the console's ``notify`` (the only console code on the session's path:
the server runs in its own thread). Also prints the whole session's time per turn with and without
the console. Usage: python benchmarks/bench_console.py [--turns N] [--viewers V]
"""
from __future__ import annotations

import argparse
import http.client
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the in-memory robot (tests/fakes.py)

from fakes import FakeRobot, ScriptedAnswers  # noqa: E402
from nao_trainer.console.server import COOKIE, Console, ConsoleHub  # noqa: E402
from nao_trainer.policies.learned import load_policy  # noqa: E402
from nao_trainer.ports import CommandQueue, NullObserver  # noqa: E402
from nao_trainer.session.behaviors import load_behaviors  # noqa: E402
from nao_trainer.session.config import load_config  # noqa: E402
from nao_trainer.session.dialogue import load_dialogue  # noqa: E402
from nao_trainer.session.engine import Session  # noqa: E402
from nao_trainer.session.record import SessionRecorder  # noqa: E402

TARGET_MS = 1.0


class TimedHub(ConsoleHub):
    """The console's hub, timing every ``notify`` on the session's thread."""

    def __init__(self) -> None:
        super().__init__()
        self.spent = 0.0
        self.calls = 0

    def notify(self, kind: str, data: dict) -> None:
        t0 = time.perf_counter()
        super().notify(kind, data)
        self.spent += time.perf_counter() - t0
        self.calls += 1


def viewer(console: Console, stop: threading.Event, received: list[int]) -> None:
    conn = http.client.HTTPConnection(console.host, console.port, timeout=10)
    conn.request("GET", "/events", headers={"Cookie": f"{COOKIE}={console.token}"})
    resp = conn.getresponse()
    n = 0
    while not stop.is_set():
        line = resp.readline()
        if not line:
            break
        n += line.startswith(b"event:")
    received.append(n)
    conn.close()


def play(turns: int, observer, out: str) -> float:
    cfg = load_config(None, {"session.turns": turns, "session.practice": False, "session.output": out,
                             "eeg.mode": "off", "timing.speed": 1.0, "session.seed": 1})
    rec = SessionRecorder(Path(out), "B")
    rec.open({})
    s = Session(cfg, FakeRobot(), ScriptedAnswers(simulated=True), load_policy("usp:2", True, Path(out) / "p.json"), rec,
                load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path),
                np.random.default_rng(1), np.random.default_rng(2), progress=None, sleep=lambda s: None,
                commands=CommandQueue(), observer=observer)
    t0 = time.perf_counter()
    s.run()
    elapsed = time.perf_counter() - t0
    rec.close(s.status, 0)
    return elapsed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--turns", type=int, default=300)
    parser.add_argument("--viewers", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as out:
        play(20, NullObserver(), out)  # warm-up (imports, caches)
        base = play(args.turns, NullObserver(), out)
        hub = TimedHub()
        console = Console.start(CommandQueue(), "127.0.0.1", 0, hub=hub)
        stop, received = threading.Event(), []
        threads = [threading.Thread(target=viewer, args=(console, stop, received), daemon=True) for _ in range(args.viewers)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 5
        while hub.viewers < args.viewers and time.monotonic() < deadline:
            time.sleep(0.01)
        with_console = play(args.turns, hub, out)
        time.sleep(0.5)
        stop.set()
        console.stop()
        for t in threads:
            t.join(timeout=5)
    per_turn_ms = 1000 * hub.spent / args.turns
    print(f"console: {args.viewers} viewers connected, {hub.calls} notifications for {args.turns} turns "
          f"({hub.calls / args.turns:.1f} per turn), events received per viewer: {sorted(received)}")
    print(f"console cost on the session thread: {per_turn_ms:.3f} ms per turn "
          f"({1e6 * hub.spent / max(1, hub.calls):.1f} us per notification)")
    print(f"whole session (in-memory robot, no waits): {1000 * base / args.turns:.3f} ms per turn without the console, "
          f"{1000 * with_console / args.turns:.3f} ms with it")
    ok = per_turn_ms < TARGET_MS
    print(f"target < {TARGET_MS} ms per turn: {'OK' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
