"""Exact evaluation of tabular policies, the finite-horizon optimum, and Monte Carlo for the rest.

Pure: no I/O. A *user* is a pair of tables over ``core.mdp``'s turn states: ``p_success`` (108,)
and ``engagement`` (108, 2). A *tabular policy* is a probability table over the observed states of
a decision process (``core.processes``) x actions, either stationary ``(n_states, 6)`` or per turn
``(turns, n_states, 6)``.

Exact evaluation (``evaluate``) is a forward recursion over the distribution of the full state
``x = (turn state, outcome)`` (``core.processes``): at each turn the mass moves through the policy and
``NEXT_TURN`` to the next turn state ``s'`` (``m_t(s')``, the probability that turn t is played in
``s'``), then splits by ``p_success[s']``. Every reported quantity is linear in ``sum_t m_t``:

    score       = sum_s' V(s') (p(s') SCORE[s', 1] + (1 - p(s')) SCORE[s', 0])
    engagement  = sum_s' V(s') (p(s') E[s', 1] + (1 - p(s')) E[s', 0]) / turns   (mean per turn)
    success     = sum_s' V(s') p(s') / turns                                      (rate per turn)
    visits[l]   = sum over s' of level l of V(s')                                  (turns per episode)

No Monte Carlo noise. ``optimal`` is the finite-horizon dynamic programme (the turn-dependent
policy with the highest expected score, an oracle). Policies that depend on the history
(staircases, learners that keep learning) are run by ``monte_carlo``: vectorised over episodes,
with 95 % t-intervals over episodes.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace, field
from typing import Any, Protocol

import numpy as np

from nao_trainer.core import distributions, mdp, processes

#: Full states that are turns (not START), and their turn state and outcome.
_X = np.arange(processes.N_FULL - 1)
_X_TURN, _X_OUT = _X // 2, _X % 2


@dataclass(frozen=True)
class Outcome:
    """Expected (or Monte Carlo mean) per-episode results of a policy on a user.

    ``score``: sum of equation (1) over the episode; ``engagement``: mean engagement per turn;
    ``success``: success rate per turn; ``visits[l-1]``: turns played at level l;
    ``level_success[l-1]``: success rate at level l (NaN when never played). ``*_ci``: 95 % interval
    (None for exact results); ``samples``: episodes simulated (0 = exact).
    """

    score: float
    engagement: float
    success: float
    visits: np.ndarray
    level_success: np.ndarray
    score_ci: tuple[float, float] | None = None
    engagement_ci: tuple[float, float] | None = None
    success_ci: tuple[float, float] | None = None
    samples: int = 0
    success_var: float | None = None  # variance of the session's success rate S/H (target-rate needs it)

    def to_dict(self) -> dict[str, Any]:
        out = {"score": self.score, "engagement": self.engagement, "success": self.success,
               "visits": self.visits.tolist(),
               "level_success": [None if not np.isfinite(v) else float(v) for v in self.level_success],
               "samples": self.samples, "success_var": self.success_var}
        for key in ("score_ci", "engagement_ci", "success_ci"):
            value = getattr(self, key)
            out[key] = None if value is None else [float(value[0]), float(value[1])]
        return out


def check_user(p_success: np.ndarray, engagement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p_success, dtype=float)
    e = np.asarray(engagement, dtype=float)
    if p.shape != (mdp.N_TURN_STATES,) or e.shape != (mdp.N_TURN_STATES, 2):
        raise ValueError(f"a user needs p_success (108,) and engagement (108, 2), got {p.shape} and {e.shape}")
    if not (np.all((p >= 0) & (p <= 1)) and np.all(np.isfinite(e))):
        raise ValueError("p_success must lie in [0, 1] and engagement must be finite")
    return p, e


def check_policy(table: np.ndarray, process: processes.DecisionProcess, turns: int) -> np.ndarray:
    """The table as (turns, n_states, 6) float; ValueError saying what does not fit the process."""
    t = np.asarray(table, dtype=float)
    n = process.n_states
    if t.shape == (n, mdp.N_ACTIONS):
        t = np.broadcast_to(t, (turns, n, mdp.N_ACTIONS))
    elif t.shape != (turns, n, mdp.N_ACTIONS):
        raise ValueError(f"policy table of shape {t.shape} does not fit the {process.name} MDP "
                         f"(needs ({n}, 6) or ({turns}, {n}, 6))")
    if np.any(t < 0) or np.any(t[:, ~process.action_mask] > 0):
        raise ValueError(f"policy table gives probability to actions not allowed in the {process.name} MDP")
    if not np.allclose(t.sum(axis=2), 1.0, atol=1e-9):
        raise ValueError("policy table rows must sum to 1")
    return t


def _transition_matrix(policy: np.ndarray, process: processes.DecisionProcess) -> np.ndarray:
    """M[x, s']: probability that the next turn is played in s' from full state x under ``policy``."""
    probs = policy[process.obs]  # (217, 6)
    valid = processes.NEXT_TURN >= 0
    rows = np.broadcast_to(np.arange(processes.N_FULL)[:, None], valid.shape)[valid]
    m = np.zeros(processes.N_FULL * mdp.N_TURN_STATES)
    np.add.at(m, rows * mdp.N_TURN_STATES + processes.NEXT_TURN[valid], probs[valid])
    return m.reshape(processes.N_FULL, mdp.N_TURN_STATES)


def turn_visits(policy: np.ndarray, p_success: np.ndarray, turns: int,
                process: "str | processes.DecisionProcess" = "paper") -> np.ndarray:
    """V(s') = expected number of turns played in each turn state over an episode (108,)."""
    proc = processes.get(process)
    table = check_policy(policy, proc, turns)
    p = np.asarray(p_success, dtype=float)
    stationary = np.shares_memory(table, table[0]) and table.strides[0] == 0
    m_static = _transition_matrix(table[0], proc) if stationary else None
    dist = np.zeros(processes.N_FULL)
    dist[processes.START_FULL] = 1.0
    total = np.zeros(mdp.N_TURN_STATES)
    for t in range(turns):
        m = dist @ (m_static if stationary else _transition_matrix(table[t], proc))
        total += m
        dist = np.empty(processes.N_FULL)
        dist[0:-1:2] = m * (1.0 - p)
        dist[1:-1:2] = m * p
        dist[-1] = 0.0
    return total


def success_moments(policy: np.ndarray, p_success: np.ndarray, turns: int,
                    process: "str | processes.DecisionProcess" = "paper") -> tuple[float, float]:
    """(E S, Var S) of a tabular policy's successes S over an episode, exactly: the chain of
    ``turn_visits`` with the successes so far carried along (full state x S)."""
    proc = processes.get(process)
    table = check_policy(policy, proc, turns)
    p = np.asarray(p_success, dtype=float)
    stationary = np.shares_memory(table, table[0]) and table.strides[0] == 0
    m_static = _transition_matrix(table[0], proc) if stationary else None
    dist = np.zeros((turns + 1, processes.N_FULL))
    dist[0, processes.START_FULL] = 1.0
    for t in range(turns):
        m = dist @ (m_static if stationary else _transition_matrix(table[t], proc))  # (S, turn states)
        dist = np.zeros((turns + 1, processes.N_FULL))
        dist[:, 0:-1:2] = m * (1.0 - p)
        dist[1:, 1:-1:2] = m[:-1] * p
    ps = dist.sum(axis=1)
    s = np.arange(turns + 1, dtype=float)
    mean = float(ps @ s)
    return mean, max(float(ps @ s ** 2) - mean ** 2, 0.0)


def summarise(visits: np.ndarray, p_success: np.ndarray, engagement: np.ndarray, turns: int) -> Outcome:
    """The ``Outcome`` of a visit vector V(s') (see the module docstring)."""
    p, e = check_user(p_success, engagement)
    score = float(visits @ (p * mdp.SCORE[:, 1] + (1 - p) * mdp.SCORE[:, 0]))
    eng = float(visits @ (p * e[:, 1] + (1 - p) * e[:, 0])) / turns
    succ = visits * p
    level_visits = np.bincount(mdp.LEVEL - 1, weights=visits, minlength=4)
    level_wins = np.bincount(mdp.LEVEL - 1, weights=succ, minlength=4)
    with np.errstate(invalid="ignore", divide="ignore"):
        level_rate = np.where(level_visits > 1e-12, level_wins / level_visits, np.nan)
    return Outcome(score, eng, float(succ.sum()) / turns, level_visits, level_rate)


def evaluate(policy: np.ndarray, p_success: np.ndarray, engagement: np.ndarray, turns: int = 25,
             process: "str | processes.DecisionProcess" = "paper") -> Outcome:
    """Exact expected results of a tabular policy on a user (no sampling; see the module docstring)."""
    p, e = check_user(p_success, engagement)
    out = summarise(turn_visits(policy, p, turns, process), p, e, turns)
    _, var = success_moments(policy, p, turns, process)
    return replace(out, success_var=var / turns ** 2)


@dataclass(frozen=True)
class Optimum:
    """The finite-horizon optimum: ``value`` at START and the deterministic ``policy`` (turns, n, 6)."""

    value: float
    policy: np.ndarray


def optimal(p_success: np.ndarray, turns: int = 25, process: "str | processes.DecisionProcess" = "paper",
            engagement: np.ndarray | None = None, engagement_weight: float = 0.0) -> Optimum:
    """Backward induction for the highest expected episode score (+ weight x engagement per turn).

    In the paper MDP the policy does not see the outcome of the turn just played; its belief about
    it is p(s) whatever the history, so the optimum over observed states is exact. Ties go to the
    lowest action index.
    """
    proc = processes.get(process)
    p = np.asarray(p_success, dtype=float)
    reward = p * mdp.SCORE[:, 1] + (1 - p) * mdp.SCORE[:, 0]
    if engagement is not None and engagement_weight:
        e = np.asarray(engagement, dtype=float)
        reward = reward + engagement_weight * (p * e[:, 1] + (1 - p) * e[:, 0])
    belief = proc.beliefs(p)  # (n, 217)
    nxt = np.where(processes.NEXT_TURN < 0, 0, processes.NEXT_TURN)  # (217, 6)
    obs_fail, obs_win = proc.obs[2 * nxt], proc.obs[2 * nxt + 1]
    policy = np.zeros((turns, proc.n_states, mdp.N_ACTIONS))
    value = np.zeros(proc.n_states)
    for t in reversed(range(turns)):
        q_full = reward[nxt] + (1 - p[nxt]) * value[obs_fail] + p[nxt] * value[obs_win]  # (217, 6)
        q = belief @ q_full
        q = np.where(proc.action_mask, q, -np.inf)
        best = q.argmax(axis=1)
        policy[t, np.arange(proc.n_states), best] = 1.0
        value = q[np.arange(proc.n_states), best]
    return Optimum(float(value[proc.start]), policy)


# ----------------------------------------------------------------------------------------------
# Monte Carlo for history-dependent policies
# ----------------------------------------------------------------------------------------------


class EpisodePolicy(Protocol):
    """A policy run on ``n`` episodes at once; it may keep any per-episode memory."""

    def reset(self, n: int, process: processes.DecisionProcess) -> None: ...

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator) -> np.ndarray: ...

    def observe(self, obs: np.ndarray, action: np.ndarray, score: np.ndarray, engagement: np.ndarray,
                next_obs: np.ndarray, done: bool) -> None: ...


@dataclass
class TablePolicy:
    """A tabular policy as an ``EpisodePolicy`` (to check Monte Carlo against ``evaluate``)."""

    table: np.ndarray
    _cum: np.ndarray | None = field(default=None, repr=False)

    def reset(self, n: int, process: processes.DecisionProcess) -> None:
        t = np.asarray(self.table, dtype=float)
        self._cum = np.cumsum(t, axis=-1)

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator) -> np.ndarray:
        cum = self._cum[turn] if self._cum.ndim == 3 else self._cum
        rows = cum[obs]
        u = rng.random(len(obs)) * rows[:, -1]
        return np.minimum((rows < u[:, None]).sum(axis=1), mdp.N_ACTIONS - 1)

    def observe(self, *args: Any) -> None:
        pass


def monte_carlo(policy: EpisodePolicy, p_success: np.ndarray, engagement: np.ndarray, episodes: int,
                rng: np.random.Generator, turns: int = 25,
                process: "str | processes.DecisionProcess" = "paper") -> Outcome:
    """Mean results over ``episodes`` simulated episodes with 95 % t-intervals over episodes."""
    proc = processes.get(process)
    p, e = check_user(p_success, engagement)
    if episodes < 2:
        raise ValueError(f"episodes must be >= 2 for an interval, got {episodes}")
    policy.reset(episodes, proc)
    full = np.full(episodes, processes.START_FULL)
    score = np.zeros(episodes)
    eng = np.zeros(episodes)
    wins = np.zeros(episodes)
    level_turns = np.zeros(4)
    level_wins = np.zeros(4)
    for t in range(turns):
        obs = proc.obs[full]
        a = np.asarray(policy.act(obs, t, rng), dtype=np.int64)
        if not np.all(proc.action_mask[obs, a]):
            raise ValueError(f"policy chose an action not allowed in the {proc.name} MDP")
        s2 = processes.NEXT_TURN[full, a]
        o2 = (rng.random(episodes) < p[s2]).astype(np.int64)
        r = mdp.SCORE[s2, o2].astype(float)
        en = e[s2, o2]
        score += r
        eng += en
        wins += o2
        lv = mdp.LEVEL[s2] - 1
        level_turns += np.bincount(lv, minlength=4)
        level_wins += np.bincount(lv, weights=o2, minlength=4)
        full = s2 * 2 + o2
        policy.observe(obs, a, r, en, proc.obs[full], t == turns - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        level_rate = np.where(level_turns > 0, level_wins / level_turns, np.nan)
    return Outcome(float(score.mean()), float(eng.mean()) / turns, float(wins.mean()) / turns,
                   level_turns / episodes, level_rate, t_interval(score), _scaled(t_interval(eng), turns),
                   _scaled(t_interval(wins), turns), episodes, float(np.var(wins / turns)))


def t_interval(values: np.ndarray) -> tuple[float, float] | None:
    """95 % t-interval of the mean (None for fewer than 2 values)."""
    v = np.asarray(values, dtype=float)
    if v.size < 2:
        return None
    half = float(distributions.t_ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return float(v.mean() - half), float(v.mean() + half)


def _scaled(ci: tuple[float, float] | None, turns: int) -> tuple[float, float] | None:
    return None if ci is None else (ci[0] / turns, ci[1] / turns)


def uniform_policy(process: "str | processes.DecisionProcess" = "paper") -> np.ndarray:
    """Uniform over the allowed actions of every state."""
    mask = processes.get(process).action_mask.astype(float)
    return mask / mask.sum(axis=1, keepdims=True)


def fixed_level_policy(level: int, process: "str | processes.DecisionProcess" = "paper") -> np.ndarray:
    """Always play a new sequence of ``level`` (1..4), never give feedback."""
    if level not in (1, 2, 3, 4):
        raise ValueError(f"level must be 1..4, got {level!r}")
    proc = processes.get(process)
    table = np.zeros((proc.n_states, mdp.N_ACTIONS))
    table[:, level - 1] = 1.0
    return table


PolicyFactory = Callable[[], EpisodePolicy]
