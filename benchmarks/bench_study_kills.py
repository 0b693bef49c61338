"""SIGKILL every study command (enrol, amend, withdraw, next) at 50 random moments and starve it of disk
(a file size limit) at 20, and count the studies left whole (issue 30's stress test).

    PYTHONPATH=. NAO_TRAINER_KEYS=$(mktemp -d) python benchmarks/bench_study_kills.py [--kills 50] [--fills 20]

The harness and what "whole" means: tests/_study_kills.py."""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _study_kills import run  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kills", type=int, default=50)
    ap.add_argument("--fills", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="study-kills-") as work:
        os.environ.setdefault("NAO_TRAINER_KEYS", str(Path(work) / "keys"))
        results = run(Path(work), args.kills, args.fills, args.seed)
    broken = sum(len(k.failures) + len(f.failures) for k, f in results.values())
    print(f"total: {sum(k.trials + f.trials for k, f in results.values())} trials, {broken} broken")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
