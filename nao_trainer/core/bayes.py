"""The exact Bayes-adaptive planner for per-level success models: the best any policy can do.

Pure: no I/O (the on-disk cache of solved tables is ``learn.bayes_cache``). numba compiles the
backward induction (``core.bayes_kernels``, imported lazily, compiled once per machine and cached by
numba; ``available()`` says whether it is installed).

Model
    A participant is one of K user models; model k succeeds at level l with probability
    ``p[k, l]``, independently from turn to turn (the level-only users of ``learn.users``). The
    prior is ``pi[k]`` (a finite mixture: the fitted clusters, the training users, or the
    evaluated users themselves). A turn at level l is worth ``u[k, l]`` to model k
    (``core.objective``: the expected score ``p (l + 1) - 1``, or ``-(p - R)^2``).

State
    What has been seen is the vector of per-level counts ``c = (s_1, f_1, ..., s_L, f_L)`` of
    successes and failures. The order of the outcomes does not matter: the posterior is

        w_k(c) ∝ pi_k  prod_l  p[k,l]^(s_l) (1 - p[k,l])^(f_l)

    so the counts are a sufficient statistic, and the turns played are ``n = sum(c)``. The
    remaining turns are ``H - n``: every state of a session of H turns is a *weak composition*
    of some n <= H into 2L parts; with L = 4 and H = 25 there are C(33, 8) = 13,884,156.

Bellman equation (backward over the layers n = H-1, ..., 0)

    Q(c, l) = ubar_l(c) + pbar_l(c) V(c + e_{s_l}) + (1 - pbar_l(c)) V(c + e_{f_l})
    V(c) = max_l Q(c, l),  V(c) = G(c) when n = H

with the posterior means ``pbar_l(c) = sum_k w_k p[k, l]`` and ``ubar_l(c) = sum_k w_k u[k, l]``
(both objectives are linear in w; for ``target:R`` ubar is the posterior expectation of
``-(p - R)^2``, not the utility of the posterior mean). ``G(c) = C max_l ubar_l(c)`` is the value
of committing to the posterior-best level for C more turns after the session (C = 0 for one
session; C = (S - 1) H for "explore this session, then commit for S - 1 sessions"), or, for an
objective on the session's success rate (``target-rate:R``), ``G(c) = T[s_1 + ... + s_L]``, a
terminal value of the session's successes, which the counts hold (the per-turn utility is then 0):
that planner is exact too. Ties go to the
lower level; counts that no model with prior weight can produce (Z = 0, possible only with rates
of exactly 0 or 1) get value 0 and the lowest level. ``V(0)`` is the Bayes value: the highest expected utility of any policy that is not
told which model the participant is, and, with the prior uniform over a set of users, the mean
over those users of what that policy earns, which is the *ceiling* of ``evaluate``.

Computation
    Layer n's states are ranked in lexicographic order (combinatorial number system, ``_OFF``
    tables), so the value of a layer is a flat array and a child ``c + e_j`` is found by its rank.
    The posterior weights are carried along the enumeration as partial products (a step changes
    the last one or two counts, so a state costs about K multiplications, not 2L K), and a layer
    is split into chunks run in parallel. Posterior means need no sum over the models: with the
    unnormalised weight ``Z(c) = sum_k pi_k prod_l p^s (1-p)^f``, ``pbar_l(c) = Z(c + e_s)/Z(c)``
    and the posterior mean of ``p^2`` is ``Z(c + 2 e_s)/Z(c)``; only Z costs K operations per
    state. Memory while solving: up to three Z layers and two value layers (the largest layer,
    n = H + 1, holds C(H + 2L, 2L - 1) doubles: 34 MB for H = 25, L = 4); kept: the action table,
    one byte per decision state (layers 0..H-1: 10.5 M states, 10.5 MB). A live decision is a
    table lookup (``Plan.decide``).

``evaluate_plan`` runs the solved policy forward on users with known rates over the states it
can reach, exactly, giving each user's expected utility, turns per level and success rate.
"""
from __future__ import annotations

import hashlib
import importlib.util
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

_KERNELS: dict[str, Any] = {}


def available() -> bool:
    """numba is installed (the planner needs it)."""
    return importlib.util.find_spec("numba") is not None


def n_states(horizon: int, levels: int) -> int:
    """Count states of a session of ``horizon`` turns (all layers, terminal included)."""
    return math.comb(horizon + 2 * levels, 2 * levels)


class PlanTooLarge(ValueError):
    """The table of a horizon would not fit in the memory allowed (raised before anything is allocated)."""

    def __init__(self, horizon: int, levels: int, needed: int, limit: int) -> None:
        self.horizon, self.levels, self.needed, self.limit = horizon, levels, needed, limit
        self.max_horizon = max_horizon(levels, limit)
        super().__init__(f"a plan of {horizon} turns at {levels} levels needs {format_bytes(needed)} of memory, more than "
                         f"the {format_bytes(limit)} available (at most {self.max_horizon} turns fit)")


def solve_bytes(horizon: int, levels: int) -> int:
    """Memory ``solve`` needs at most (bytes): the action table (one byte per decision state) and up to
    five float layers (three Z, two V) of the largest layer it touches (n = H + 2), computed without
    allocating anything."""
    m = 2 * levels
    table = math.comb(horizon - 1 + m, m)  # decision states: layers 0..H-1
    return table + 5 * 8 * math.comb(horizon + 2 + m - 1, m - 1)


def max_horizon(levels: int, limit: int) -> int:
    """The longest horizon whose ``solve_bytes`` fits in ``limit`` (0 when not even one turn does)."""
    h = 0
    while solve_bytes(h + 1, levels) <= limit:
        h += 1
    return h


def format_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} EiB"  # pragma: no cover


def _offsets_table(m: int, horizon: int) -> np.ndarray:
    """OFF[d, nrem, x] = number of weak compositions whose part d is < x, given nrem left for parts d.."""
    off = np.zeros((m - 1, horizon + 2, horizon + 3), dtype=np.int64)
    for d in range(m - 1):
        parts = m - d - 1  # parts after d
        for nrem in range(horizon + 2):
            acc = 0
            for x in range(nrem + 2):
                off[d, nrem, x] = acc
                if x <= nrem:
                    acc += math.comb(nrem - x + parts - 1, parts - 1)
    return off


def layer_sizes(horizon: int, levels: int) -> np.ndarray:
    m = 2 * levels
    return np.array([math.comb(n + m - 1, m - 1) for n in range(horizon + 1)], dtype=np.int64)


def rank_many(counts: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Ranks within their layer of count rows (N, 2L) (vectorised ``_rank``)."""
    c = np.asarray(counts, dtype=np.int64)
    nrem = c.sum(axis=1)
    r = np.zeros(len(c), dtype=np.int64)
    for d in range(c.shape[1] - 1):
        r += off[d, nrem, c[:, d]]
        nrem = nrem - c[:, d]
    return r


# ----------------------------------------------------------------------------------------------
# The compiled backward induction
# ----------------------------------------------------------------------------------------------


def _kernels() -> dict[str, Any]:
    """The compiled layer kernels (``core.bayes_kernels``, imported here: numba is optional)."""
    if not _KERNELS:
        try:
            from nao_trainer.core import bayes_kernels
        except ImportError:  # pragma: no cover - checked by available()
            raise ImportError("the Bayes planner needs numba: pip install 'nao-trainer[all]'") from None
        _KERNELS.update(_z_layer=bayes_kernels.z_layer, _v_layer=bayes_kernels.v_layer,
                        _successes=bayes_kernels.successes_layer)
    return _KERNELS


# ----------------------------------------------------------------------------------------------
# Plans
# ----------------------------------------------------------------------------------------------


def _check(p: np.ndarray, weights: np.ndarray, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p = np.asarray(p, dtype=float)
    w = np.asarray(weights, dtype=float)
    cf = np.asarray(coef, dtype=float)
    if p.ndim != 2 or p.shape[0] < 1 or p.shape[1] < 1:
        raise ValueError(f"success rates must be a (models, levels) table, got shape {p.shape}")
    if not np.all((p >= 0) & (p <= 1)):
        raise ValueError("success rates must lie in [0, 1]")
    if w.shape != (p.shape[0],) or np.any(w < 0) or not w.sum() > 0 or not np.all(np.isfinite(w)):
        raise ValueError(f"prior weights must be {p.shape[0]} non-negative numbers with a positive sum")
    if cf.shape != (p.shape[1], 3) or not np.all(np.isfinite(cf)):
        raise ValueError(f"utility coefficients must be a finite ({p.shape[1]}, 3) table (a, b, c of a + b p + c p^2)")
    return p, w / w.sum(), cf


def utility_table(p: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """u[k, l] = a_l + b_l p[k, l] + c_l p[k, l]^2."""
    p = np.asarray(p, dtype=float)
    cf = np.asarray(coef, dtype=float)
    return cf[:, 0] + cf[:, 1] * p + cf[:, 2] * p ** 2


def fingerprint(p: np.ndarray, weights: np.ndarray, coef: np.ndarray, horizon: int, commit: int = 0,
                terminal: np.ndarray | None = None) -> str:
    """A hash of everything a plan depends on (prior, objective, horizon, commit turns, terminal)."""
    p, w, cf = _check(p, weights, coef)
    h = hashlib.sha256()
    h.update(f"bayes-v1|{horizon}|{commit}|{p.shape}".encode())
    for arr in (p, w, cf):
        h.update(np.round(arr, 12).astype("<f8").tobytes())
    if terminal is not None:  # plans without one keep their old keys (the on-disk cache stays valid)
        h.update(b"|terminal|" + np.round(np.asarray(terminal, float), 12).astype("<f8").tobytes())
    return h.hexdigest()


def _check_terminal(terminal: np.ndarray | None, horizon: int, commit: int) -> np.ndarray | None:
    if terminal is None:
        return None
    t = np.asarray(terminal, dtype=float)
    if t.shape != (horizon + 1,) or not np.all(np.isfinite(t)):
        raise ValueError(f"the terminal value must be {horizon + 1} finite numbers (one per success count)")
    if commit:
        raise ValueError("a terminal value on the session's successes and commit turns do not combine")
    return t


@dataclass(frozen=True, eq=False)
class Plan:
    """A solved Bayes-adaptive policy: ``action[offsets[n] + rank]`` is the level index (0-based) to
    play in the state of layer n with that rank; ``value`` = V(0)."""

    p: np.ndarray
    weights: np.ndarray
    coef: np.ndarray
    horizon: int
    commit: int
    action: np.ndarray
    value: float
    fingerprint: str
    terminal: np.ndarray | None = None  # G[S] by the session's successes (target-rate), else None

    @property
    def levels(self) -> int:
        return self.p.shape[1]

    @property
    def utility(self) -> np.ndarray:
        return utility_table(self.p, self.coef)

    @property
    def offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(layer_sizes(self.horizon, self.levels)[:-1])])

    def decide(self, counts: "np.ndarray | list[int]") -> int:
        """The level (1-based) to play after these per-level (successes, failures) counts."""
        c = np.asarray(counts, dtype=np.int64).reshape(-1)
        if c.shape != (2 * self.levels,) or np.any(c < 0):
            raise ValueError(f"counts must be {2 * self.levels} non-negative numbers (s1, f1, ..., sL, fL)")
        n = int(c.sum())
        if n >= self.horizon:
            raise ValueError(f"the plan covers {self.horizon} turns; {n} have been played")
        off = _offsets(self.horizon, self.levels)
        r = 0
        nrem = n
        for d in range(len(c) - 1):
            r += int(off[d, nrem, c[d]])
            nrem -= int(c[d])
        return int(self.action[int(self.offsets[n]) + r]) + 1

    def decide_many(self, counts: np.ndarray) -> np.ndarray:
        """``decide`` for rows of counts (N, 2L) that have all played the same number of turns: (N,) levels."""
        c = np.asarray(counts, dtype=np.int64)
        n = int(c[0].sum()) if len(c) else 0
        if c.ndim != 2 or c.shape[1] != 2 * self.levels or np.any(c < 0) or np.any(c.sum(axis=1) != n):
            raise ValueError(f"counts must be rows of {2 * self.levels} non-negative numbers with one sum")
        if n >= self.horizon:
            raise ValueError(f"the plan covers {self.horizon} turns; {n} have been played")
        ranks = rank_many(c, _offsets(self.horizon, self.levels))
        return self.action[int(self.offsets[n]) + ranks].astype(np.int64) + 1

    def memory_bytes(self) -> int:
        return int(self.action.nbytes)


_OFF_CACHE: dict[tuple[int, int], np.ndarray] = {}


def _offsets(horizon: int, levels: int) -> np.ndarray:
    key = (horizon, levels)
    if key not in _OFF_CACHE:
        _OFF_CACHE[key] = _offsets_table(2 * levels, horizon + 2)
    return _OFF_CACHE[key]


def solve(p: np.ndarray, weights: np.ndarray, coef: np.ndarray, horizon: int, commit: int = 0,
          chunks: int = 64, max_bytes: int | None = None, terminal: np.ndarray | None = None) -> Plan:
    """Backward induction over every count state (module docstring). ``p``: (K, L) success rates of
    the models, ``weights``: their prior, ``coef``: (L, 3) utility ``a + b p + c p^2`` per level.
    ``max_bytes``: ``PlanTooLarge`` before any allocation when ``solve_bytes`` exceeds it.
    ``terminal``: the value of ending with S = 0..horizon successes (``Objective.terminal``)."""
    p, w, cf = _check(p, weights, coef)
    term = _check_terminal(terminal, horizon, commit)
    if horizon < 1:
        raise ValueError(f"the horizon must be at least one turn, got {horizon}")
    if commit < 0:
        raise ValueError(f"commit turns must be >= 0, got {commit}")
    k_models, levels = p.shape
    if max_bytes is not None and solve_bytes(horizon, levels) > max_bytes:
        raise PlanTooLarge(horizon, levels, solve_bytes(horizon, levels), max_bytes)
    m = 2 * levels
    off = _offsets(horizon, levels)
    sizes = layer_sizes(horizon + 2, levels)
    pw = np.empty((m, horizon + 3, k_models))
    x = np.arange(horizon + 3, dtype=float)[:, None]
    for lv in range(levels):
        pw[2 * lv] = np.where(x == 0, 1.0, p[:, lv][None, :] ** x)
        pw[2 * lv + 1] = np.where(x == 0, 1.0, (1.0 - p[:, lv])[None, :] ** x)
    kern = _kernels()
    zl, vl = kern["_z_layer"], kern["_v_layer"]

    def z_of(n: int) -> np.ndarray:
        z = np.empty(sizes[n])
        zl(n, off, pw, w, z, max(1, min(chunks, int(sizes[n]))))
        return z

    offsets = np.concatenate([[0], np.cumsum(sizes[:horizon])])
    action = np.zeros(int(sizes[:horizon].sum()), dtype=np.int8)
    quadratic = bool(np.any(cf[:, 2] != 0))
    empty = np.zeros(1)
    dummy = np.zeros(1, dtype=np.int8)
    if commit > 0:  # the terminal layer needs Z on layers H .. H+2
        z2 = z_of(horizon + 2) if quadratic else empty
        z1, z0 = z_of(horizon + 1), z_of(horizon)
        vnext = np.empty(sizes[horizon])
        vl(horizon, horizon, off, cf, z0, z1, z2, vnext, vnext, dummy, float(commit),
           max(1, min(chunks, int(sizes[horizon]))))
    else:  # V = 0 after the last turn, or the terminal value of the session's successes
        z1 = z_of(horizon + 1) if quadratic else empty
        z0 = z_of(horizon)
        vnext = np.zeros(sizes[horizon])
        if term is not None:
            s_tot = np.empty(sizes[horizon], dtype=np.int64)
            kern["_successes"](horizon, off, s_tot, max(1, min(chunks, int(sizes[horizon]))))
            vnext = np.where(z0 > 0.0, term[s_tot], 0.0)
            del s_tot
    for n in range(horizon - 1, -1, -1):
        z2, z1, z0 = (z1 if quadratic else empty), z0, z_of(n)
        vcur = np.empty(sizes[n])
        act = action[offsets[n]:offsets[n] + sizes[n]]
        vl(n, horizon, off, cf, z0, z1, z2, vnext, vcur, act, float(commit), max(1, min(chunks, int(sizes[n]))))
        vnext = vcur
    return Plan(p, w, cf, horizon, commit, action, float(vnext[0]), fingerprint(p, w, cf, horizon, commit, term),
                term)


def posterior_weights(p: np.ndarray, weights: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """w_k(c) of the module docstring (normalised); counts = (s1, f1, ..., sL, fL)."""
    p = np.asarray(p, dtype=float)
    c = np.asarray(counts, dtype=float).reshape(-1)
    with np.errstate(divide="ignore"):
        logw = np.log(np.asarray(weights, dtype=float))
        for lv in range(p.shape[1]):
            for j, q in ((2 * lv, p[:, lv]), (2 * lv + 1, 1.0 - p[:, lv])):
                if c[j] > 0:
                    logw = logw + c[j] * np.log(q)
    if not np.isfinite(logw).any():
        raise ValueError("no user model can produce these counts")
    w = np.exp(logw - logw.max())
    return w / w.sum()


# ----------------------------------------------------------------------------------------------
# Running a plan on users with known rates
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanValue:
    """Per user (rows): expected utility over the session, over the commit turns after it, turns per
    level, successes per session."""

    session: np.ndarray  # (U,)
    commit: np.ndarray  # (U,)
    visits: np.ndarray  # (U, L)
    successes: np.ndarray  # (U,)
    successes_var: np.ndarray | None = None  # (U,) variance of the session's successes

    @property
    def total(self) -> np.ndarray:
        return self.session + self.commit


def evaluate_plan(plan: Plan, p_true: np.ndarray) -> PlanValue:
    """Exact expected results of ``plan`` on each user (rows of ``p_true``, (U, L)), under the plan's
    objective."""
    offsets = plan.offsets
    off = _offsets(plan.horizon, plan.levels)

    def choose(states: np.ndarray, n: int) -> np.ndarray:
        return plan.action[offsets[n] + rank_many(states, off)].astype(np.int64)

    p_true = np.atleast_2d(np.asarray(p_true, dtype=float))
    value, visits, succ, succ_var, states, mass = _forward(choose, p_true, plan.coef, plan.horizon,
                                                           terminal=plan.terminal)
    commit = np.zeros(len(value))
    if plan.commit > 0:  # the posterior-best level, played for ``commit`` turns after the session
        u_true = utility_table(p_true, plan.coef)
        for i, c in enumerate(states):
            lv = int(np.argmax(np.round(posterior_weights(plan.p, plan.weights, c) @ plan.utility, 12)))
            commit += plan.commit * mass[i] * u_true[:, lv]
    return PlanValue(value, commit, visits, succ, succ_var)


def evaluate_rule(choose: Any, p_true: np.ndarray, coef: np.ndarray, horizon: int,
                  terminal: np.ndarray | None = None) -> PlanValue:
    """Exact expected results of any policy that depends on the counts only: ``choose(states (R, 2L),
    n) -> level indices (R,)`` for the states of layer n it can reach; run forward on each user."""
    value, visits, succ, var = _forward(choose, np.atleast_2d(np.asarray(p_true, float)), coef, horizon,
                                        terminal=terminal)[:4]
    return PlanValue(value, np.zeros_like(value), visits, succ, var)


def _forward(choose: Any, p_true: np.ndarray, coef: np.ndarray, horizon: int, start: np.ndarray | None = None,
             n0: int = 0, terminal: np.ndarray | None = None) -> tuple:
    """Exact forward run of ``choose`` from the state ``start`` of layer ``n0`` (default: the empty
    counts of layer 0) to the end of the session, for each user (rows of ``p_true``): (value, visits,
    expected successes from n0, variance of the session's successes, final states, their mass);
    ``terminal[S]`` is added to the value (the session's successes, ``start``'s included)."""
    p_true = np.atleast_2d(np.asarray(p_true, dtype=float))
    u_true = utility_table(p_true, coef)
    levels = p_true.shape[1]
    off = _offsets(horizon, levels)
    n_users, m = p_true.shape[0], 2 * levels
    states = np.zeros((1, m), dtype=np.int64) if start is None else np.asarray(start, np.int64).reshape(1, m)
    mass = np.ones((1, n_users))
    value = np.zeros(n_users)
    visits = np.zeros((n_users, levels))
    succ = np.zeros(n_users)
    for n in range(n0, horizon):
        a = np.asarray(choose(states, n), dtype=np.int64)
        pa = p_true[:, a].T  # (R, U)
        value += (mass * u_true[:, a].T).sum(axis=0)
        succ += (mass * pa).sum(axis=0)
        for lv in range(levels):
            visits[:, lv] += mass[a == lv].sum(axis=0)
        rows = np.arange(len(states))
        win, lose = states.copy(), states.copy()
        win[rows, 2 * a] += 1
        lose[rows, 2 * a + 1] += 1
        cand = np.concatenate([win, lose])
        cmass = np.concatenate([mass * pa, mass * (1.0 - pa)])
        keep = cmass.max(axis=1) > 0
        cand, cmass = cand[keep], cmass[keep]
        keys = rank_many(cand, off)
        uniq, first, inv = np.unique(keys, return_index=True, return_inverse=True)
        new = np.zeros((len(uniq), n_users))
        for u in range(n_users):
            new[:, u] = np.bincount(inv, weights=cmass[:, u], minlength=len(uniq))
        states, mass = cand[first], new
    s_final = states[:, 0::2].sum(axis=1)
    mean_s = (mass * s_final[:, None]).sum(axis=0)
    var = np.maximum((mass * s_final[:, None].astype(float) ** 2).sum(axis=0) - mean_s ** 2, 0.0)
    if terminal is not None:
        value = value + (mass * np.asarray(terminal, float)[s_final][:, None]).sum(axis=0)
    return value, visits, succ, var, states, mass


# ----------------------------------------------------------------------------------------------
# Checking that a table is the plan of its inputs (a stored table may be torn, stale or crafted)
# ----------------------------------------------------------------------------------------------


def _bayes_value_from(plan: Plan, state: np.ndarray, n0: int, first: int | None = None) -> float:
    """The Bayes value of ``plan`` from ``state`` (layer ``n0``), playing level index ``first`` there
    instead of the plan's when given: the posterior mixture of each model's exact expected utility."""
    offsets = plan.offsets
    off = _offsets(plan.horizon, plan.levels)

    def choose(states: np.ndarray, n: int) -> np.ndarray:
        if n == n0 and first is not None:
            return np.full(len(states), first, dtype=np.int64)
        return plan.action[offsets[n] + rank_many(states, off)].astype(np.int64)

    value, _, _, _, ends, mass = _forward(choose, plan.p, plan.coef, plan.horizon, state, n0, plan.terminal)
    if plan.commit > 0:
        u = plan.utility
        for i, c in enumerate(ends):
            lv = int(np.argmax(np.round(posterior_weights(plan.p, plan.weights, c) @ u, 12)))
            value = value + plan.commit * mass[i] * u[:, lv]
    return float(posterior_weights(plan.p, plan.weights, state) @ value)


def plan_problem(plan: Plan) -> str | None:
    """Why ``plan`` is not the Bayes-optimal plan of its inputs (None when the checks pass).

    A sample of states is solved again from the table itself: the table's own Bayes value must be
    its stored ``value``; at the first state and at both states it can lead to after one turn no
    other first level may do better (a one-step deviation, then the table: the policy improvement
    test, exact); and every last-turn state it reaches must play the posterior-best level. A table
    edited anywhere it is played at the start (say every action made level 4) fails the first two."""
    tol = 1e-9 * (1.0 + abs(plan.value))
    m = 2 * plan.levels
    root = np.zeros(m, dtype=np.int64)
    own = _bayes_value_from(plan, root, 0)
    if not abs(own - plan.value) <= tol:
        return f"its stored value {plan.value!r} is not the value of its actions ({own!r})"
    a0 = int(plan.action[0])
    states = [(root, 0)]
    if plan.horizon > 1:
        for j in (2 * a0, 2 * a0 + 1):
            child = root.copy()
            child[j] += 1
            states.append((child, 1))
    for state, n in states:
        if posterior_weights_or_none(plan, state) is None:
            continue
        best = _bayes_value_from(plan, state, n)
        for lv in range(plan.levels):
            q = _bayes_value_from(plan, state, n, lv)
            if q > best + tol:
                return (f"at counts {state.tolist()} level {lv + 1} is worth {q:.9g}, more than the table's level "
                        f"{plan.decide(state)} ({best:.9g})")
    return _last_layer_problem(plan)


def posterior_weights_or_none(plan: Plan, counts: np.ndarray) -> np.ndarray | None:
    try:
        return posterior_weights(plan.p, plan.weights, counts)
    except ValueError:
        return None


def _last_layer_problem(plan: Plan) -> str | None:
    """Every state of the last turn the table reaches plays the posterior-best level (with commit turns:
    the level best for this turn and the commitment after it)."""
    n = plan.horizon - 1
    offsets = plan.offsets
    off = _offsets(plan.horizon, plan.levels)

    def choose(states: np.ndarray, layer: int) -> np.ndarray:
        return plan.action[offsets[layer] + rank_many(states, off)].astype(np.int64)

    states = _forward(choose, plan.p, plan.coef, n)[4] if n > 0 else np.zeros((1, 2 * plan.levels), np.int64)
    u = plan.utility
    for c in states:
        w = posterior_weights_or_none(plan, c)
        if w is None:
            continue
        q = np.empty(plan.levels)
        for lv in range(plan.levels):
            q[lv] = w @ u[:, lv]
            if plan.terminal is not None:  # the session's successes after this last turn
                s_now, pk = int(c[0::2].sum()), float(w @ plan.p[:, lv])
                q[lv] += pk * plan.terminal[s_now + 1] + (1.0 - pk) * plan.terminal[s_now]
            if plan.commit > 0:
                for j, pk in ((2 * lv, plan.p[:, lv]), (2 * lv + 1, 1.0 - plan.p[:, lv])):
                    child = c.copy()
                    child[j] += 1
                    prob = float(w @ pk)
                    wc = posterior_weights_or_none(plan, child)
                    if prob > 0 and wc is not None:
                        q[lv] += prob * plan.commit * float(np.max(wc @ u))
        a = int(plan.action[int(offsets[n]) + int(rank_many(c[None], off)[0])])
        if q[a] < q.max() - 1e-9 * (1.0 + abs(q.max())):
            return f"at counts {c.tolist()} of the last turn it plays level {a + 1}, not the best level {int(np.argmax(q)) + 1}"
    return None
