"""Benchmark: a hyper-parameter sweep of 400 beta points x 3 user models x 20 seeds x 10,000 episodes.

Target: <= 10 minutes on this 2-core machine. By default this measures a fraction of the points
(``--points 20``, the same work per point) and extrapolates linearly, saying so; ``--points 400``
runs the whole sweep. Work items are (point, user model) pairs fanned out over local processes
(``learn.parallel``); each trains 20 learners (the compiled kernel) and scores their frozen
policies exactly.

    python benchmarks/bench_sweep.py [--points N] [--workers N] [--param beta1|beta2]
"""
from __future__ import annotations

import argparse
import sys
import time

from nao_trainer.experiments import sweep
from nao_trainer.learn.users import cluster_user_set

FULL_POINTS, TARGET_S = 400, 600.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--param", default="beta1", choices=["beta1", "beta2"])
    args = ap.parse_args()
    hi = 10.0 if args.param == "beta1" else 2.0
    # The measured points are spread over the full range (the cost does not depend on the value much).
    spec = sweep.make_spec([f"{args.param}=0:{hi}:{args.points}"], seeds=20, episodes=10_000)
    users = cluster_user_set(None)
    turns = args.points * len(users) * 20 * 10_000 * 25
    print(f"sweep: {args.points} {args.param} points x {len(users)} user models x 20 seeds x 10,000 episodes x 25 turns "
          f"= {turns / 1e9:.2f} G turns, {args.workers} workers")
    t0 = time.perf_counter()
    results = sweep.run(spec, users, workers=args.workers)
    wall = time.perf_counter() - t0
    assert len(results) == args.points * len(users)
    full = wall * FULL_POINTS / args.points
    what = "measured" if args.points == FULL_POINTS else f"extrapolated from {args.points} points x {FULL_POINTS / args.points:g}"
    print(f"  {wall:.1f} s for {args.points} points ({turns / wall / 1e6:.1f} M turns/s)")
    print(f"400 points: {full:.0f} s ({what}); target <= {TARGET_S:.0f} s {'OK' if full <= TARGET_S else 'MISSED'}")
    return 0 if full <= TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
