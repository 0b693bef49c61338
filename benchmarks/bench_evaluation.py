"""Benchmark: exact evaluation of one tabular policy on one user simulator (target <= 1 ms).

Times ``core.evaluation.evaluate`` (forward recursion over 25 turns, validation included) for a
stochastic policy (a trained learner's softmax, shipped policy usp_2_qaug) and for the per-turn
optimum, in both decision processes, and the finite-horizon optimum itself.

    python benchmarks/bench_evaluation.py [--repeat N]
"""
from __future__ import annotations

import argparse
import sys
import time

from nao_trainer.core import baselines, evaluation
from nao_trainer.learn import artifacts, policy_files

TARGET_MS = 1.0


def timed(fn, repeat: int) -> float:
    fn()
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - t0) / repeat)
    return best * 1e3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    sim = artifacts.load_simulator("2")
    path = policy_files.default_policies_dir() / policy_files.policy_filename("2", "qaug")
    learner = policy_files.learner_from_payload(policy_files.read_policy_file(path), path)
    table = baselines.learner_table(learner)
    p, e = sim.p_success, sim.engagement
    ok = True
    for name, fn in (
        ("usp_2_qaug frozen (paper MDP, stationary)", lambda: evaluation.evaluate(table, p, e)),
        ("uniform random (informed MDP)", lambda: evaluation.evaluate(evaluation.uniform_policy("informed"), p, e, 25,
                                                                      "informed")),
        ("optimum policy (per turn, paper MDP)", lambda: evaluation.evaluate(opt.policy, p, e)),
        ("finite-horizon optimum itself (paper)", lambda: evaluation.optimal(p, 25, "paper")),
    ):
        if name.startswith("optimum policy"):
            opt = evaluation.optimal(p, 25, "paper")
        ms = timed(fn, args.repeat)
        judged = "optimum itself" not in name and "per turn" not in name
        verdict = ("OK" if ms <= TARGET_MS else "MISSED") if judged else "(not judged)"
        ok &= ms <= TARGET_MS or not judged
        print(f"{name:<45} {ms:7.3f} ms  {verdict}")
    print(f"target: one stationary policy on one simulator in <= {TARGET_MS:g} ms")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
