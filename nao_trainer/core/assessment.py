"""Personalising for a new participant: assess, match the user models, choose a policy, keep learning.

Pure: no I/O. The pipeline (paper, section 6 and Figure 9, plus a per-participant Bayesian layer):

1. **Assessment.** The first turns follow a schedule of levels (``assessment_schedule``: by default
   two turns each at levels 2, 3 and 4). They are scored like any turn.
2. **Posterior.** After every turn the posterior over the known user models and the participant's
   per-level Beta posteriors are updated (``core.posterior``).
3. **Policy choice by posterior expected value.** Each candidate policy (the user-specific policy
   of every model, each fixed level) has an exact expected score over the remaining turns on every
   model from the current state (``value_tables``: backward recursion, no sampling). Their
   posterior-weighted mean, corrected by the participant's per-level shifts, is the candidate's
   expected value::

       EV_c = sum_k w_k [ V_ck(r, x) + sum_l N_ckl(r, x) * (l + 1) * delta_kl ]

   ``V_ck(r, x)``: expected score of candidate c on model k over the ``r`` remaining turns from the
   full state ``x`` (turn state and outcome of the turn just played, which the robot knows);
   ``N_ckl(r, x)``: the expected number of those turns at level l; ``(l + 1) * delta_kl``: the
   change of a level-l turn's expected score (+l on success, -1 on failure) when the participant's
   success rate there is ``delta_kl`` above the model's (exact for fixed levels on level-only
   models; first order otherwise).
4. **No flip-flopping.** The chosen candidate is kept unless another one's expected value is
   higher by more than ``margin`` points (default 0.5) over the remaining turns. Re-decided
   after every turn once the assessment is over.
5. **Keep learning, and try.** With the per-level Beta posteriors learning (finite ``kappa``), a
   *probe* is valued too: play level l for the next m turns (m in ``probes``, default 1-3), then
   follow the best candidate given what those turns showed (``probe_values``: the outcomes averaged
   over the posterior predictive, so the value of the information counts). The turn plays the
   probe's level when its value beats the followed candidate's by more than ``margin``; the
   candidate itself does not change. This is expected value over the remaining turns with a short
   look-ahead; greedy choice among candidates alone never leaves a level the prior likes.

``mode=Choice.MOST_LIKELY`` (``"map"``) is the paper's pipeline for comparison: after the assessment, the most likely model
under the plain posterior (``kappa = inf``) is taken and its policy followed to the end.

``Personaliser`` runs ``n`` participants at once (``core.evaluation.EpisodePolicy``, for Monte
Carlo); the live policy (``policies.personalised``) runs one.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from math import comb
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import mdp, processes, task
from nao_trainer.core.posterior import FLOOR, ModelSet, log_likelihood, normalise, shifts

DEFAULT_LEVELS: tuple[int, ...] = (2, 3, 4)
#: d(expected score of a level-l turn) / d(success rate) = l + 1 (+l on success, -1 on failure).
_SCORE_SLOPE = np.arange(2, 6, dtype=float)
DEFAULT_LENGTH = 6


class Choice(str, Enum):
    """How the personaliser chooses the candidate to follow after the assessment."""

    EXPECTED_VALUE = "ev"  #: the posterior expected value over the remaining turns, with probes (the pipeline)
    MOST_LIKELY = "map"  #: the most likely model's own policy, kept to the end (the paper's pipeline)


MODES: tuple[str, ...] = tuple(c.value for c in Choice)


def assessment_schedule(length: int = DEFAULT_LENGTH, levels: Sequence[int] = DEFAULT_LEVELS) -> tuple[int, ...]:
    """``length`` turns in consecutive blocks over ``levels``, as equal as possible (earlier blocks longer).

    ``assessment_schedule(6)`` = (2, 2, 3, 3, 4, 4); ``assessment_schedule(4)`` = (2, 2, 3, 4).
    """
    if length < 0:
        raise ValueError(f"assessment length must be >= 0, got {length}")
    if not levels or any(lv not in (1, 2, 3, 4) for lv in levels):
        raise ValueError(f"assessment levels must be 1..4, got {list(levels)}")
    base, extra = divmod(length, len(levels))
    out: list[int] = []
    for i, lv in enumerate(levels):
        out += [int(lv)] * (base + (1 if i < extra else 0))
    return tuple(out)


def value_tables(policy: np.ndarray, p_success: np.ndarray, turns: int,
                 process: "str | processes.DecisionProcess" = "paper") -> tuple[np.ndarray, np.ndarray]:
    """(V, N) of a stationary policy on a user: V[r, x] expected score, N[r, x, l] expected turns at
    level l+1, over the next ``r`` turns (0..turns) from full state ``x`` (``core.processes``).

    ``V[turns, START_FULL]`` equals ``core.evaluation.evaluate(...).score``.
    """
    proc = processes.get(process)
    table = np.asarray(policy, dtype=float)
    if table.shape != (proc.n_states, mdp.N_ACTIONS):
        raise ValueError(f"policy table of shape {table.shape} does not fit the {proc.name} MDP")
    valid = processes.NEXT_TURN >= 0
    nxt = np.where(valid, processes.NEXT_TURN, 0)  # (217, 6)
    pi = np.where(valid, table[proc.obs], 0.0)
    p = np.asarray(p_success, dtype=float)[nxt]
    reward = p * mdp.SCORE[nxt, 1] + (1.0 - p) * mdp.SCORE[nxt, 0]
    onehot = np.eye(4)[mdp.LEVEL[nxt] - 1]  # (217, 6, 4)
    fail, win = 2 * nxt, 2 * nxt + 1
    v = np.zeros((turns + 1, processes.N_FULL))
    n = np.zeros((turns + 1, processes.N_FULL, 4))
    for r in range(1, turns + 1):
        v[r] = (pi * (reward + p * v[r - 1][win] + (1.0 - p) * v[r - 1][fail])).sum(axis=1)
        cont = p[..., None] * n[r - 1][win] + (1.0 - p)[..., None] * n[r - 1][fail]
        n[r] = (pi[..., None] * (onehot + cont)).sum(axis=1)
    return v, n


@dataclass(frozen=True)
class Candidate:
    """A policy the personaliser may follow: a stationary probability table over observed states."""

    name: str
    table: np.ndarray


def _log_beta_ratio(a: np.ndarray, b: np.ndarray, k: int, j: int) -> np.ndarray:
    """log B(a + k, b + j) - log B(a, b) for whole k, j >= 0: the log-probability of one ordered run of k
    successes and j failures under a Beta(a, b) rate.

    By B(a + 1, b) = B(a, b) a / (a + b) it is a sum of 2 (k + j) logs (k, j <= 3 here). It is the log-gamma
    form to 1e-13 (whose differences lose digits at small a), without scipy.special: that cost each session
    0.3 s of CPU to import for this one function.
    """
    out = np.zeros(np.broadcast(a, b).shape)
    for i in range(k):
        out += np.log(a + i)
    for i in range(j):
        out += np.log(b + i)
    for i in range(k + j):
        out -= np.log(a + b + i)
    return out


@dataclass
class Personaliser:
    """The pipeline of the module docstring for ``n`` participants at once.

    ``own_policy[k]``: index in ``candidates`` of model k's user-specific policy (``Choice.MOST_LIKELY``).
    ``start_log_w``, ``start_wins``, ``start_turns``: where a returning participant's posterior
    stands (default: the prior, no turns).
    """

    models: ModelSet
    candidates: list[Candidate]
    schedule: tuple[int, ...] = assessment_schedule()
    kappa: float = 10.0
    margin: float = 0.5
    turns: int = 25
    mode: Choice | str = Choice.EXPECTED_VALUE
    own_policy: tuple[int, ...] = ()
    process: str = "paper"
    start_log_w: np.ndarray | None = None
    start_wins: np.ndarray | None = None
    start_turns: np.ndarray | None = None
    start_map_log_w: np.ndarray | None = None
    probes: tuple[int, ...] = (1, 2, 3)
    _v: np.ndarray = field(init=False, repr=False)
    _n: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"personaliser mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        self.mode = Choice(self.mode)
        if not self.candidates:
            raise ValueError("the personaliser needs at least one candidate policy")
        if self.kappa <= 0:
            raise ValueError(f"kappa must be > 0 (inf: no per-level learning), got {self.kappa}")
        if self.margin < 0:
            raise ValueError(f"margin must be >= 0, got {self.margin}")
        if self.mode is Choice.MOST_LIKELY and len(self.own_policy) != self.models.k:
            raise ValueError("mode 'map' needs own_policy: one candidate index per model")
        c, k, t = len(self.candidates), self.models.k, self.turns
        self._v = np.zeros((c, k, t + 1, processes.N_FULL))
        self._n = np.zeros((c, k, t + 1, processes.N_FULL, 4))
        for i in range(c):
            self._tables_for(i)
        self.reset(1, processes.get(self.process))

    def _tables_for(self, i: int) -> None:
        for k in range(self.models.k):
            self._v[i, k], self._n[i, k] = value_tables(self.candidates[i].table, self.models.p_success[k],
                                                        self.turns, self.process)

    def set_candidate_table(self, i: int, table: np.ndarray) -> None:
        """A candidate changed (a Q-learner that keeps learning): recompute its value tables."""
        self.candidates[i] = Candidate(self.candidates[i].name, np.asarray(table, dtype=float))
        self._tables_for(i)

    # -- core.evaluation.EpisodePolicy ------------------------------------------------------------

    def reset(self, n: int, process: "processes.DecisionProcess | str") -> None:
        self._proc = processes.get(process)
        k = self.models.k
        lw = np.log(self.models.prior) if self.start_log_w is None else np.asarray(self.start_log_w, dtype=float)
        self.log_w = np.tile(lw, (n, 1))
        # the plain posterior (kappa = inf), for Choice.MOST_LIKELY
        self.map_log_w = self.log_w.copy() if self.start_map_log_w is None else np.tile(
            np.asarray(self.start_map_log_w, dtype=float), (n, 1))
        self.wins = np.tile(np.zeros(4) if self.start_wins is None else np.asarray(self.start_wins, float), (n, 1))
        self.played = np.tile(np.zeros(4) if self.start_turns is None else np.asarray(self.start_turns, float), (n, 1))
        self.full = np.full(n, processes.START_FULL)
        self.current = np.full(n, -1)
        self.switches = np.zeros(n, dtype=np.int64)
        self.probes_played = np.zeros(n, dtype=np.int64)
        self.probing = np.zeros(n, dtype=bool)
        self.last_ev = np.zeros((n, len(self.candidates)))
        self.turn = 0
        assert self.log_w.shape == (n, k)

    def in_assessment(self, turn: int) -> bool:
        return turn < len(self.schedule)

    def expected_values(self, turn: int) -> np.ndarray:
        """(n, C): posterior expected score of each candidate over the remaining turns."""
        return self._ev(self.log_w, self.wins, self.played, self.full, max(self.turns - turn, 0))

    def _ev(self, log_w: np.ndarray, wins: np.ndarray, played: np.ndarray, full: "np.ndarray | int",
            r: int) -> np.ndarray:
        """(n, C) expected values (``expected_values``) for given posteriors; ``full`` (n,) or one state."""
        w = normalise(log_w)  # (n, K)
        delta = shifts(self.models, wins, played, self.kappa) * _SCORE_SLOPE  # (n, K, 4)
        if np.ndim(full) == 0:
            v = self._v[:, :, r, int(full)]  # (C, K)
            nl = self._n[:, :, r, int(full)]  # (C, K, 4)
            return w @ v.T + np.einsum("nk,ckl,nkl->nc", w, nl, delta, optimize=True)
        v = self._v[:, :, r, full]  # (C, K, n)
        nl = self._n[:, :, r, full]  # (C, K, n, 4)
        gain = np.einsum("cknl,nkl->ckn", nl, delta)
        return np.einsum("nk,ckn->nc", w, v + gain)

    def _beta(self, wins: np.ndarray, played: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
        """(a, b) (n, K): each model's Beta posterior of the participant's success at ``level`` (1..4)."""
        m = np.clip(self.models.level_means[None, :, level - 1], FLOOR, 1.0 - FLOOR)
        w, n = wins[:, None, level - 1], played[:, None, level - 1]
        return self.kappa * m + w, self.kappa * (1.0 - m) + (n - w)

    def probe_values(self, turn: int) -> np.ndarray:
        """(n, 4): the best expected score over the remaining turns of first playing level l for
        m in ``probes`` turns, then following the best candidate given what those turns showed.

        The outcomes of the probe are averaged over the posterior predictive (a Beta-binomial under
        each model, mixed by the posterior): the value of the information is counted, which a
        choice among candidates alone never does. Needs a finite ``kappa`` (with the models as
        fitted nothing is learned about the participant's own rates).
        """
        n_ep = self.log_w.shape[0]
        r = self.turns - turn
        out = np.full((n_ep, 4), -np.inf)
        if not np.isfinite(self.kappa):
            return out
        w = normalise(self.log_w)
        for level in (1, 2, 3, 4):
            a, b = self._beta(self.wins, self.played, level)
            p_next = (w * a / (a + b)).sum(axis=1)  # predictive success of one turn at this level
            length = task.LENGTHS[level - 1]
            x_win = 2 * mdp.encode(length, 0, level) + 1
            x_fail = 2 * mdp.encode(length, 0, -level)
            for m in self.probes:
                if m >= r:
                    continue
                total = m * ((level + 1) * p_next - 1.0)
                for k in range(m + 1):
                    seq = _log_beta_ratio(a, b, k, m - k)  # (n, K)
                    prob = comb(m, k) * (w * np.exp(seq)).sum(axis=1)
                    lw = self.log_w + seq
                    wins, played = self.wins.copy(), self.played.copy()
                    wins[:, level - 1] += k
                    played[:, level - 1] += m
                    after = 0.0
                    for x, share in ((x_win, k / m), (x_fail, 1.0 - k / m)):
                        if share > 0:
                            after = after + share * self._ev(lw, wins, played, x, r - m).max(axis=1)
                    total = total + prob * after
                out[:, level - 1] = np.maximum(out[:, level - 1], total)
        return out

    def decide(self, turn: int, bonus: np.ndarray | None = None) -> np.ndarray:
        """The candidate each participant follows from this turn on (the anti-flip-flop rule);
        ``bonus`` (n, C) is added to the candidates' values first (e.g. the supervisor's guidance)."""
        if self.mode is Choice.MOST_LIKELY:
            fresh = self.current < 0
            if fresh.any():
                best = normalise(self.map_log_w[fresh]).argmax(axis=1)
                self.current[fresh] = np.asarray(self.own_policy)[best]
            return self.current
        ev = self.expected_values(turn)
        if bonus is not None:
            ev = ev + bonus
        self.last_ev = ev
        best = ev.argmax(axis=1)
        rows = np.arange(len(best))
        keep = self.current >= 0
        cur_ev = np.where(keep, ev[rows, np.maximum(self.current, 0)], -np.inf)
        switch = (~keep) | (ev[rows, best] > cur_ev + self.margin)
        self.switches += switch & keep & (best != self.current)
        self.current = np.where(switch, best, self.current)
        return self.current

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator,
            bonus: np.ndarray | None = None) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.int64)
        if self.in_assessment(turn):
            self.probing = np.zeros(len(obs), dtype=bool)
            return np.full(len(obs), self.schedule[turn] - 1)
        chosen = self.decide(turn, bonus)
        tables = np.stack([c.table for c in self.candidates])  # (C, n_states, 6)
        probs = tables[chosen, obs]  # (n, 6)
        cum = np.cumsum(probs, axis=1)
        u = rng.random(len(obs)) * cum[:, -1]
        action = np.minimum((cum < u[:, None]).sum(axis=1), mdp.N_ACTIONS - 1)
        self.probing = np.zeros(len(obs), dtype=bool)
        if self.mode is Choice.EXPECTED_VALUE and self.probes and np.isfinite(self.kappa):
            probe = self.probe_values(turn)  # (n, 4)
            commit = self.last_ev[np.arange(len(obs)), chosen]
            self.probing = probe.max(axis=1) > commit + self.margin
            action = np.where(self.probing, probe.argmax(axis=1), action)
            self.probes_played += self.probing
        return action

    def observe(self, obs: np.ndarray, action: np.ndarray, score: np.ndarray, engagement: np.ndarray | None,
                next_obs: np.ndarray, done: bool) -> None:
        s2 = np.asarray(self._proc.turn_of(np.asarray(next_obs)), dtype=np.int64)
        success = np.asarray(score) > 0
        self.update(s2, success, engagement)

    def update(self, state: np.ndarray, success: np.ndarray, engagement: np.ndarray | None = None) -> None:
        """One turn played in turn states ``state`` (n,) with outcomes ``success`` (n,)."""
        state = np.atleast_1d(np.asarray(state, dtype=np.int64))
        success = np.atleast_1d(np.asarray(success, dtype=bool))
        e = None if engagement is None else np.atleast_1d(np.asarray(engagement, dtype=float))
        delta = shifts(self.models, self.wins, self.played, self.kappa)
        self.log_w = self.log_w + log_likelihood(self.models, state, success, delta, e)
        self.map_log_w = self.map_log_w + log_likelihood(self.models, state, success, np.zeros_like(delta), e)
        lv = mdp.LEVEL[state] - 1
        rows = np.arange(len(state))
        self.played[rows, lv] += 1
        self.wins[rows, lv] += success
        self.full = state * 2 + success
        self.turn += 1

    # -- one participant's state (a live session saves and restores it) ---------------------------

    def snapshot(self, row: int = 0) -> dict[str, Any]:
        """Participant ``row``'s whole state as JSON-ready values (``restore`` goes back to it)."""
        return {"log_w": self.log_w[row].tolist(), "map_log_w": self.map_log_w[row].tolist(),
                "wins": self.wins[row].tolist(), "played": self.played[row].tolist(),
                "current": int(self.current[row]), "switches": int(self.switches[row]), "full": int(self.full[row]),
                "turn": self.turn, "schedule": list(self.schedule)}

    def restore(self, data: dict[str, Any], row: int = 0) -> None:
        """Participant ``row`` back to a ``snapshot`` (its assessment schedule and turn included)."""
        self.log_w[row] = data["log_w"]
        self.map_log_w[row] = data["map_log_w"]
        self.wins[row], self.played[row] = data["wins"], data["played"]
        self.current[row], self.switches[row], self.full[row] = data["current"], data["switches"], data["full"]
        self.turn = int(data["turn"])
        self.schedule = tuple(int(x) for x in data["schedule"])

    # -- what it believes (for the record and the console) ----------------------------------------

    def posterior(self) -> np.ndarray:
        """(n, K): the posterior over the user models."""
        return normalise(self.log_w)

    def level_estimates(self) -> np.ndarray:
        """(n, 4): the participant's posterior mean success rate per level."""
        w = self.posterior()
        m = self.models.level_means[None] + shifts(self.models, self.wins, self.played, self.kappa)
        return np.clip(np.einsum("nk,nkl->nl", w, m), 0.0, 1.0)
