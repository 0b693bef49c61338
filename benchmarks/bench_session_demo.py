"""How long the demo session takes (issue 2: `make demo` plays 25 turns in under a minute).

Runs the demo study in-process against the stand-in over qi and prints wall time, time per turn
and the session engine's own CPU time. Usage: python benchmarks/bench_session_demo.py [--turns N]
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time

os.environ.setdefault("QI_LOG_LEVEL", "silent")

from nao_trainer.session.config import load_config  # noqa: E402
from nao_trainer.session.wiring import RunOptions, run_session  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--turns", type=int, default=25)
    parser.add_argument("--speed", type=float, default=None, help="default: the demo study's speed")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as out:
        overrides = {"session.turns": args.turns, "session.output": out, "timing.speed": args.speed}
        config = load_config(None, overrides)
        cpu0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        result = run_session(config, RunOptions(quiet=True))
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    print(f"demo session: {args.turns} turns at speed {config.timing.speed:g}, status {result.status}")
    verdict = "" if args.turns != 25 else (" OK" if wall < 60 else " MISSED")
    print(f"  wall time          {wall:7.2f} s   (target < 60 s for 25 turns){verdict}")
    print(f"  per turn           {wall / args.turns:7.3f} s")
    print(f"  CPU (this process) {cpu:7.2f} s   ({100 * cpu / wall:.0f} % of one core)")
    return 0 if result.exit_code == 0 and (args.turns != 25 or wall < 60) else 1


if __name__ == "__main__":
    sys.exit(main())
