"""Benchmark: the exact Bayes-adaptive planner (``core.bayes``) for a 25-turn, four-level session.

Targets (issue 21): the table in at most 5 s on this 2-core machine, at most 1 ms per live
decision, memory stated. The prior is 50 user models (seeded random per-level success rates, like
the 50 per-session users; the time does not depend on the rates) under both objectives. Prints
the first call in a fresh process with an empty numba cache (compiling) and with it filled (loading
the compiled kernels, as every later process on the machine does), the solve time (best of ``--repeat``), the
cache load time, the time of one live decision (``Plan.decide``) and the memory of the table.

    python benchmarks/bench_bayes.py [--repeat 2] [--turns 25] [--models 50]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from nao_trainer.core import bayes, objective
from nao_trainer.learn import bayes_cache

TARGET_S, TARGET_DECISION_MS = 5.0, 1.0


FIRST_CALL = ("import time, numpy as np; from nao_trainer.core import bayes, objective; t = time.perf_counter(); "
              "bayes.solve(np.array([[0.9, 0.5], [0.6, 0.3]]), np.ones(2), objective.SCORE.coefficients()[:2], 3); "
              "print(time.perf_counter() - t)")


def first_call_s(numba_cache: str) -> float:
    """Seconds of the first solve in a new process whose numba cache is ``numba_cache``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=numba_cache)
    out = subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--turns", type=int, default=25)
    ap.add_argument("--models", type=int, default=50)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    p = np.sort(rng.uniform(0.2, 0.99, (args.models, 4)), axis=1)[:, ::-1]
    w = np.ones(args.models)
    with tempfile.TemporaryDirectory() as numba_cache:
        compiled, loaded = first_call_s(numba_cache), first_call_s(numba_cache)
    print(f"first call in a process: {compiled:.1f} s compiling (empty numba cache, once per machine), "
          f"{loaded:.2f} s loading the compiled kernels (every later process)")
    bayes.solve(p[:2], w[:2], objective.SCORE.coefficients(), 3)
    states = bayes.n_states(args.turns, 4)
    for obj in (objective.SCORE, objective.parse("target:0.75")):
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            plan = bayes.solve(p, w, obj.coefficients(), args.turns)
            best = min(best, time.perf_counter() - t0)
        ok = "ok" if best <= TARGET_S else "over target"
        print(f"{obj}: {states:,} states, {args.models} models, solve {best:.2f} s (target {TARGET_S:g} s: {ok}); "
              f"V(0) = {plan.value:.4f}")
    with tempfile.TemporaryDirectory() as tmp:
        bayes_cache.solve_cached(p, w, objective.SCORE.coefficients(), args.turns, folder=Path(tmp))
        t0 = time.perf_counter()
        bayes_cache.solve_cached(p, w, objective.SCORE.coefficients(), args.turns, folder=Path(tmp))
        took = time.perf_counter() - t0
        size = sum(f.stat().st_size for f in Path(tmp).glob("*.npz"))
        print(f"load from the disk cache: {took:.3f} s (the table on disk: {size / 1e6:.2f} MB compressed)")
    counts = np.zeros(8, dtype=np.int64)
    decisions = []
    for _ in range(args.turns):
        t0 = time.perf_counter()
        lv = plan.decide(counts)
        decisions.append(time.perf_counter() - t0)
        counts[2 * (lv - 1) + int(rng.random() < p[0, lv - 1])] += 1
    ms = 1e3 * float(np.median(decisions))
    print(f"live decision (Plan.decide): median {ms:.3f} ms, max {1e3 * max(decisions):.3f} ms "
          f"(target {TARGET_DECISION_MS:g} ms: {'ok' if ms <= TARGET_DECISION_MS else 'over target'})")
    live_psychometric(args.turns, rng)
    layer = int(bayes.layer_sizes(args.turns + 2, 4).max())
    print(f"memory: action table {plan.memory_bytes() / 1e6:.1f} MB (kept); while solving also about "
          f"{5 * layer * 8 / 1e6:.0f} MB of value and weight layers")
    return 0


def live_psychometric(turns: int, rng: np.random.Generator) -> None:
    """The live policy as ``run --policy bayes --prior psychometric`` builds it (the shipped pooled
    prior, 78 spans), under target:0.75: its solve at start-up and its decisions (``BayesPolicy.decide``)."""
    from nao_trainer.policies.bayes import load_bayes

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        pol = load_bayes(None, "bench", turns, "target:0.75", False, "psychometric", cache=Path(tmp))
        solve = time.perf_counter() - t0
    truth = pol.p[len(pol.p) // 2]
    decisions = []
    for _ in range(turns):
        t0 = time.perf_counter()
        lv = pol.decide()
        decisions.append(time.perf_counter() - t0)
        pol.counts[2 * (lv - 1) + int(rng.random() >= truth[lv - 1])] += 1
    ms = 1e3 * float(np.median(decisions))
    print(f"live bayes, psychometric prior (target:0.75, {len(pol.p)} spans): start-up solve {solve:.2f} s; "
          f"decision median {ms:.3f} ms, max {1e3 * max(decisions):.3f} ms "
          f"(target {TARGET_DECISION_MS:g} ms: {'ok' if ms <= TARGET_DECISION_MS else 'over target'})")


if __name__ == "__main__":
    raise SystemExit(main())
