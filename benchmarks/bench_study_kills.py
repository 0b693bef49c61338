"""SIGKILL every study command (enrol, amend, withdraw, next) at 50 random moments and starve it of disk
(a file size limit) at 20, and count the studies left whole (issue 30's stress test).

    PYTHONPATH=. NAO_TRAINER_KEYS=$(mktemp -d) python benchmarks/bench_study_kills.py [--kills 50] [--fills 20]

The harness and what "whole" means: tests/_study_kills.py. With ``--registry postgresql``: a throwaway
PostgreSQL cluster (tests/_pg_cluster.py): ``study enrol`` from two sites killed at --kills moments, then
--kills rounds of a site's ``study next`` and ``study record`` each killed at a random moment, the
registry checked after a whole ``study record`` (tests/_pg_kills.py)."""
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
    ap.add_argument("--registry", choices=("sqlite", "postgresql"), default="sqlite")
    args = ap.parse_args()
    if args.registry == "postgresql":
        return _postgresql(args)
    with tempfile.TemporaryDirectory(prefix="study-kills-") as work:
        os.environ.setdefault("NAO_TRAINER_KEYS", str(Path(work) / "keys"))
        results = run(Path(work), args.kills, args.fills, args.seed)
    broken = sum(len(k.failures) + len(f.failures) for k, f in results.values())
    print(f"total: {sum(k.trials + f.trials for k, f in results.values())} trials, {broken} broken")
    return 1 if broken else 0


def _postgresql(args) -> int:
    from _pg_cluster import Cluster, find_bin
    from _pg_kills import run as run_pg
    from _pg_kills import run_sessions

    if find_bin() is None:
        print("PostgreSQL server binaries not found: install the OS package postgresql")
        return 2
    cluster = Cluster(Path(tempfile.mkdtemp(prefix="nao-trainer-pg-")))
    cluster.start()
    try:
        with tempfile.TemporaryDirectory(prefix="study-kills-pg-") as work:
            r = run_pg(cluster, Path(work), args.kills, args.seed)
            for f in r.failures:
                print("BROKEN", f)
            print(f"postgresql: {r.trials} killed enrolments ({r.enrolled} completed before the kill), "
                  f"{len(r.failures)} broken", flush=True)
        with tempfile.TemporaryDirectory(prefix="study-kills-pg-") as work:
            s = run_sessions(cluster, Path(work), args.kills, args.seed)
            for f in s.failures:
                print("BROKEN", f)
            print(f"postgresql: {s.trials} rounds of a killed study next and a killed study record ({s.enrolled} "
                  f"sessions ended before the kill), {len(s.failures)} broken")
    finally:
        cluster.stop()
    return 1 if r.failures or s.failures else 0


if __name__ == "__main__":
    sys.exit(main())
