"""The compiled backward induction of ``core.bayes`` (numba kernels, compiled once per machine).

In a module of their own so that numba's on-disk cache (``cache=True``: ``__pycache__`` beside
this file, or numba's user-wide cache folder when that is read-only) keys them by this file: a
process that finds them compiled loads them in a fraction of a second instead of compiling for
about 7 s. Like a ``.pyc``, the cache is numba's, not data; a changed file is compiled again.
Imported only when a plan is solved (numba is an optional dependency).
"""
from __future__ import annotations

import numba
import numpy as np
from numba import prange

__all__ = ["z_layer", "v_layer", "successes_layer"]


@numba.njit(cache=True, nogil=True)
def _unrank(r, n, off, c):
    m = c.shape[0]
    nrem = n
    for d in range(m - 1):
        x = 0
        while x + 1 <= nrem and off[d, nrem, x + 1] <= r:
            x += 1
        c[d] = x
        r -= off[d, nrem, x]
        nrem -= x
    c[m - 1] = nrem


@numba.njit(cache=True, nogil=True)
def _successor(c):
    """Next weak composition in lexicographic order (in place); returns the first part that changed."""
    m = c.shape[0]
    tail = c[m - 1]
    d = m - 2
    while tail == 0:
        tail += c[d]
        d -= 1
    c[d] += 1
    for j in range(d + 1, m - 1):
        c[j] = 0
    c[m - 1] = tail - 1
    return d


@numba.njit(cache=True, parallel=True, fastmath=True)  # fastmath: only the sum over models
def z_layer(n, off, pw, prior, z, chunks):
    """Z(c) = sum_k pi_k prod_j pw[j, c_j, k] for every state c of layer n (partial products carried)."""
    m = off.shape[0] + 1
    k_models = prior.shape[0]
    size = z.shape[0]
    for ch in prange(chunks):
        start = ch * size // chunks
        stop = (ch + 1) * size // chunks
        if start >= stop:
            continue
        c = np.zeros(m, dtype=np.int64)
        _unrank(start, n, off, c)
        partial = np.empty((m + 1, k_models))
        partial[0, :] = prior
        for j in range(m):
            for k in range(k_models):
                partial[j + 1, k] = partial[j, k] * pw[j, c[j], k]
        for idx in range(start, stop):
            if idx > start:
                d = _successor(c)
                for j in range(d, m):
                    for k in range(k_models):
                        partial[j + 1, k] = partial[j, k] * pw[j, c[j], k]
            total = 0.0
            for k in range(k_models):
                total += partial[m, k]
            z[idx] = total


@numba.njit(cache=True, parallel=True, fastmath=False)
def v_layer(n, horizon, off, coef, z0, z1, z2, vnext, vcur, act, commit, chunks):
    """Values (and actions) of layer n from layer n + 1. ``z0, z1, z2``: Z on layers n, n+1, n+2.

    With u = a + b p + c p^2 per level: pbar_l = Z(c + e_s)/Z(c) and the posterior mean of p^2 is
    Z(c + 2 e_s)/Z(c), so no sum over the models is needed here. The ranks of c + e_j and
    c + 2 e_j come from prefix and suffix sums of the rank's terms (O(1) per child)."""
    m = off.shape[0] + 1
    levels = coef.shape[0]
    size, terminal = vcur.shape[0], n == horizon
    quadratic = z2.shape[0] > 1  # c != 0 for some level: Z of layer n + 2 was computed
    for ch in prange(chunks):
        start = ch * size // chunks
        stop = (ch + 1) * size // chunks
        if start >= stop:
            continue
        c, nrem = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
        p1, p2, sf = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
        _unrank(start, n, off, c)
        for idx in range(start, stop):
            if idx > start:
                _successor(c)
            zc = z0[idx]
            if zc <= 0.0:  # no model can produce these counts
                vcur[idx] = 0.0
                if not terminal:
                    act[idx] = 0
                continue
            left, a1, a2 = n, 0, 0
            for d in range(m):
                nrem[d] = left
                p1[d] = a1
                p2[d] = a2
                if d < m - 1:
                    a1 += off[d, left + 1, c[d]]
                    a2 += off[d, left + 2, c[d]]
                left -= c[d]
            acc = 0
            for d in range(m - 1, -1, -1):
                sf[d] = acc
                if d < m - 1:
                    acc += off[d, nrem[d], c[d]]
            best, best_a = -1e300, 0
            for lv in range(levels):
                s = 2 * lv
                rs = p1[s] + off[s, nrem[s] + 1, c[s] + 1] + sf[s]
                ps = z1[rs] / zc
                u = coef[lv, 0] + coef[lv, 1] * ps
                if quadratic:
                    rss = p2[s] + off[s, nrem[s] + 2, c[s] + 2] + sf[s]
                    u += coef[lv, 2] * (z2[rss] / zc)
                if terminal:
                    q = commit * u
                else:
                    f = s + 1
                    if f < m - 1:
                        rf = p1[f] + off[f, nrem[f] + 1, c[f] + 1] + sf[f]
                    else:
                        rf = p1[f]
                    q = u + ps * vnext[rs] + (1.0 - ps) * vnext[rf]
                if q > best + 1e-12:
                    best = q
                    best_a = lv
            vcur[idx] = best
            if not terminal:
                act[idx] = best_a


@numba.njit(cache=True, parallel=True)
def successes_layer(n, off, out, chunks):
    """out[rank] = total successes (sum of the even parts) of every state of layer n."""
    m = off.shape[0] + 1
    size = out.shape[0]
    for ch in prange(chunks):
        start = ch * size // chunks
        stop = (ch + 1) * size // chunks
        if start >= stop:
            continue
        c = np.zeros(m, dtype=np.int64)
        _unrank(start, n, off, c)
        for idx in range(start, stop):
            if idx > start:
                _successor(c)
            total = 0
            for j in range(0, m, 2):
                total += c[j]
            out[idx] = total
