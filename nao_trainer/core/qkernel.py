"""A compiled (numba) kernel for ``core.batch.BatchLearner``: the same maths, one agent at a time.

Pure: no I/O. numba is imported lazily (``available()`` says whether it is installed); without it
``BatchLearner`` runs its numpy loop. The kernel runs one agent's whole training from that agent's
uniforms, in the order the numpy learner uses them (``u[episode, turn, 0]`` chooses the action,
``u[episode, turn, 1]`` draws the outcome), with the same float operations in the same order, so the
tables and episode results are bit-identical for the same random numbers (tests compare them).

One caveat, stated so it is not discovered later: the softmax weights use ``exp``; numpy's
vectorised ``exp`` and the C library's ``exp`` used here can differ in the last bit. Weights enter
only through comparisons with ``u * total``, so an action can differ only when a uniform falls
within about 1e-16 (relative) of a decision boundary; no such case occurred in the tests or the
benchmarks (which compare every table).
"""
from __future__ import annotations

import importlib.util
import signal
import threading
from typing import Any

import numpy as np

_KERNEL: Any = None

MIN_EXPONENT, MAX_EXPONENT = -700.0, 700.0


def available() -> bool:
    """numba is installed (the compiled kernel can be used)."""
    return importlib.util.find_spec("numba") is not None


def kernel():
    """The compiled ``run_agent`` (compiled on first use, cached on disk by numba)."""
    global _KERNEL
    if _KERNEL is None:
        try:
            import numba
        except ImportError:  # pragma: no cover - checked by available()
            raise ImportError("the compiled learner needs numba: pip install 'nao-trainer[all]'") from None
        _KERNEL = _signals_held_while_compiling(numba.njit(cache=True, nogil=True)(_run_agent))
    return _KERNEL


def _signals_held_while_compiling(dispatcher):
    """``dispatcher`` with Ctrl-C and SIGTERM held (blocked, not lost) while it compiles or loads its cache.

    numba compiles through LLVM, which installs signal handlers of its own meanwhile; a Ctrl-C in those
    moments ended `nao-trainer train` with -2 (killed by SIGINT: no clean-up, no message) in 1 of 30 runs on a
    loaded machine, in none of 30 with the signals held. Held, it reaches Python when the call returns, as a
    signal during any compiled call does anyway (compiled code runs no Python handler): no later than before.
    """
    held = {signal.SIGINT, signal.SIGTERM}

    def call(*args):
        if dispatcher.signatures or threading.current_thread() is not threading.main_thread():
            return dispatcher(*args)
        before = signal.pthread_sigmask(signal.SIG_BLOCK, held)
        try:
            return dispatcher(*args)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)

    call.py_func = dispatcher.py_func
    return call


def _run_agent(u, nt, p_next, obs_of, reward, e, inv_tau, q, h, qv, counts, visits,
               beta2, alpha, gamma, start_obs, start_code, n_start, codes):  # pragma: no cover - compiled
    """Train one agent over ``u.shape[0]`` episodes; tables (A, S) are updated in place.

    ``nt[code * A + a]``: 2 x the next turn state (the code of its failure); ``p_next``: its
    P(success); ``obs_of[code]``: observed state; ``reward`` / ``e``: r' and engagement of a code;
    ``codes[k, t]``: the code reached by turn t of episode k (for the episode sums).
    """
    n_actions = q.shape[0]
    episodes, turns = u.shape[0], u.shape[1]
    last = turns - 1
    cum = np.empty(n_actions)
    for k in range(episodes):
        gs = start_obs
        code = start_code
        top = 0.0
        for t in range(turns):
            vis = visits[gs]
            inv = inv_tau[vis]
            n = n_start if t == 0 else n_actions
            if t == 0:
                top = qv[0, gs]
                for j in range(1, n):
                    v = qv[j, gs]
                    top = v if v > top else top
            total = 0.0
            for j in range(n):
                z = qv[j, gs] - top
                z *= inv
                if z < MIN_EXPONENT:
                    z = MIN_EXPONENT
                if z > MAX_EXPONENT:
                    z = MAX_EXPONENT
                w = np.exp(z)
                total = w if j == 0 else total + w
                cum[j] = total
            thr = u[k, t, 0] * total
            a = 0
            for j in range(n - 1):
                if cum[j] < thr:
                    a += 1
            idx = code * n_actions + a
            code2 = nt[idx] + (1 if u[k, t, 1] < p_next[idx] else 0)
            gs2 = obs_of[code2]
            codes[k, t] = code2
            target = reward[code2]
            if t != last:
                top = q[0, gs2]
                for j in range(1, n_actions):
                    v = q[j, gs2]
                    top = v if v > top else top
                target = target + gamma * top
            q_sa = q[a, gs]
            q_new = q_sa + alpha * (target - q_sa)
            q[a, gs] = q_new
            cnt = counts[a, gs] + 1
            counts[a, gs] = cnt
            h_sa = h[a, gs]
            h_new = h_sa + (e[code2] - h_sa) / cnt
            h[a, gs] = h_new
            qv[a, gs] = q_new + beta2 * h_new
            visits[gs] = vis + 1
            gs = gs2
            code = code2
