"""Compile numba's kernels into their on-disk cache once, before `make test` starts its workers.

Without this, every test worker (and every nao-trainer process a test starts) that reaches a kernel before
the first compile is written compiles it again: about 9 s of CPU for all of them, 1 s to load them once
cached (measured 2026-12-08), paid several times over by 4 workers. The calls are tiny but have the argument
types the project passes (float64 arrays, int64 tables), so numba keys them as the real calls: a suite run
after this one adds no signature to the cache. Without numba (an optional dependency) it does nothing.
"""
from __future__ import annotations

import numpy as np

from nao_trainer.core import bayes, mdp, qkernel
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import METHODS


def main() -> None:
    if not qkernel.available():
        return
    p = np.array([[0.9, 0.7, 0.5, 0.3], [0.8, 0.6, 0.4, 0.2]])
    w = np.array([0.5, 0.5])
    linear = np.column_stack([np.zeros(4), np.arange(1.0, 5.0), np.zeros(4)])
    quadratic = linear + np.column_stack([np.zeros(4), np.zeros(4), np.full(4, -0.5)])
    for coef in (linear, quadratic):
        bayes.solve(p, w, coef, horizon=3)
        bayes.solve(p, w, coef, horizon=3, commit=1)
        bayes.solve(p, w, coef, horizon=3, terminal=np.linspace(0.0, 1.0, 4))
    rng = np.random.default_rng(0)
    for process in ("paper", "informed"):
        learner = BatchLearner(np.full((1, mdp.N_TURN_STATES), 0.5), np.full((1, mdp.N_TURN_STATES, 2), 0.5),
                               [METHODS[0]], process=process, engine="numba")
        learner.run(2, 3, [rng])


if __name__ == "__main__":
    main()
