"""Tabular Q-learning with engagement as feedback (paper section 5.2).

Pure: no I/O, no global randomness. Two implementations of the *same* maths:

* ``QLearner``: one agent, for live sessions (``act`` / ``update``);
* ``core.batch.BatchLearner``: many independent agents (cluster x method x seed) in lock-step over
  simulated users, vectorised with numpy (or compiled, ``core.qkernel``). Tests check that both
  produce identical actions and tables when fed the same random numbers.

Learning rule
    ``Q(s, a) <- Q(s, a) + alpha * (r' + gamma * max_b Q(s', b) - Q(s, a))``; on the last turn of an
    episode the bracket is ``r' - Q(s, a)`` (no bootstrap). ``r = SCORE[s', o']`` is the paper's
    equation (1) for the turn played in ``s'`` (+level on success, -1 on failure).

Engagement as feedback (``method``)
    ``performance``  ``r' = r``; actions chosen on ``Q``.
    ``shaping``      ``r' = r + beta1 * e`` (beta1 = 7.5); actions chosen on ``Q``.
    ``qaug``         ``r' = r``; actions chosen on ``Q'(s, a) = Q(s, a) + beta2 * H(s, a)`` (beta2 = 0.8).

    ``e`` in [0, 1] is the engagement of the turn played in ``s'``. ``H(s, a)`` is the engagement
    model of the pair: the *incremental sample mean* of the engagement observed after taking ``a`` in
    ``s``, ``H <- H + (e - H) / n(s, a)``, starting at ``h_prior`` (0 by default, so untried pairs
    are not favoured). ``H`` and its counts are kept for every method (they cost nothing and let a
    policy be inspected), but only ``qaug`` uses them. A turn without engagement (``e is None``,
    live only) uses ``r' = r`` and leaves ``H`` unchanged.

Exploration
    Softmax (Boltzmann) over the allowed actions with a temperature that falls with the number of
    times ``n`` the agent has acted in that state::

        tau(n) = max(tau_min, tau0 / (1 + n / n_half))      P(a | s) ~ exp(V(s, a) / tau(n(s)))

    With ``tau0 = 5`` the first choices are near-uniform: early action values differ by about
    ``alpha * 4 = 0.3`` (the reward scale is -1..+4 per turn, more with shaping), ``exp(0.3 / 5) = 1.06``.
    The temperature halves after ``n_half = 200`` visits and floors at ``tau_min = 0.1`` (reached
    after ~10,000 visits), leaving a little exploration forever (which also keeps the live policy
    probabilistic, like Figure 8). ``n_half`` was chosen by comparing 20, 200 and 1000 on the
    shipped user models (5 seeds x 10,000 episodes): 20 cools too fast and locks some seeds into
    poor policies, 1000 is still exploring at the end. In ``START`` only the level actions L1..L4
    are allowed (``mdp.ACTION_MASK``).

Sampling an action from a uniform ``u`` is inverse-CDF over the allowed actions in index order:
the first action whose cumulative weight reaches ``u`` times the total.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from nao_trainer.core import mdp, processes
from nao_trainer.core.settings import SettingError, setting, settings

METHODS: tuple[str, ...] = ("performance", "shaping", "qaug")
METHOD_TEXT: dict[str, str] = {
    "performance": "r' = r (task score, eq. 1)",
    "shaping": "r' = r + beta1 * e (reward shaping)",
    "qaug": "choose on Q + beta2 * H(s,a) (Q-augmentation)",
}


def check_method(method: str) -> str:
    """``method`` if it is one of ``METHODS``; ValueError naming the bad value otherwise."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    return method


@settings
class QConfig:
    """Hyper-parameters (paper defaults; the temperature schedule is this project's, see module doc).

    Each field carries its rule (``core.settings``): one validator and one message style, as for the
    study configuration (``key 'alpha' must be <= 1, got 1.5``); a ``SettingError`` is a ``ValueError``."""

    alpha: float = setting(0.08, kind=(int, float), above=0, max=1, doc="learning rate, (0, 1]")
    gamma: float = setting(0.95, kind=(int, float), min=0, max=1, doc="discount factor, [0, 1]")
    tau0: float = setting(5.0, kind=(int, float), above=0, doc="initial temperature, > 0")
    tau_min: float = setting(0.1, kind=(int, float), above=0, doc="temperature floor, (0, tau0]")
    n_half: float = setting(200.0, kind=(int, float), above=0, doc="visits that halve the temperature, > 0")
    beta1: float = setting(7.5, kind=(int, float), doc="engagement weight of reward shaping (finite)")
    beta2: float = setting(0.8, kind=(int, float), doc="engagement weight of Q-augmentation (finite)")
    h_prior: float = setting(0.0, kind=(int, float), min=0, max=1, doc="prior engagement H, [0, 1]")

    def __post_init__(self) -> None:
        if self.tau_min > self.tau0:
            raise SettingError("tau_min", f"must be <= tau0 ({self.tau0:g}), got {self.tau_min!r}")

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "QConfig":
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown hyper-parameter(s): {', '.join(sorted(unknown))}")
        return cls(**{k: float(v) for k, v in data.items()})

    def shaping_weight(self, method: str) -> float:
        """beta1 for ``shaping``, 0 otherwise (the reward weight of engagement)."""
        return self.beta1 if check_method(method) == "shaping" else 0.0

    def augment_weight(self, method: str) -> float:
        """beta2 for ``qaug``, 0 otherwise (the action-value weight of H)."""
        return self.beta2 if check_method(method) == "qaug" else 0.0


def inverse_temperature(visits: "int | np.ndarray", config: QConfig) -> np.ndarray:
    """``1 / tau(n)`` for visit counts ``n`` (vectorised; see the module doc for tau)."""
    n = np.asarray(visits, dtype=np.float64)
    if np.any(n < 0):
        raise ValueError(f"visit counts must be >= 0, got {n.min()!r}")
    tau = np.maximum(config.tau_min, config.tau0 / (1.0 + n / config.n_half))
    return 1.0 / tau


def temperature(visits: "int | np.ndarray", config: QConfig) -> np.ndarray:
    """``tau(n) = max(tau_min, tau0 / (1 + n / n_half))``."""
    return 1.0 / inverse_temperature(visits, config)


#: Exponents are clamped to this range. Below it exp() underflows to 0 anyway (and numpy's exp is
#: several times slower on underflowing inputs); above it exp() would overflow. With the exact
#: column maximum as the shift no exponent exceeds 0; with the reused shift (see ``softmax_weights``)
#: the default hyper-parameters keep exponents far inside the range, and no setting can produce inf
#: or NaN probabilities.
MIN_EXPONENT, MAX_EXPONENT = -700.0, 700.0


def softmax_weights(values: np.ndarray, inv_tau: np.ndarray, top: np.ndarray | None = None) -> np.ndarray:
    """Unnormalised Boltzmann weights of the columns of ``values`` (k actions, n agents).

    ``top`` (n,) is subtracted from every column before scaling so that large values at small
    temperatures cannot overflow; by default the exact column maximum. The learners pass instead
    ``max_b Q(s', b)``, which their previous update computed anyway: it differs from the maximum of
    the values chosen on by at most ``beta2`` (qaug's ``beta2 * H`` with H in [0, 1]) plus one
    update step when ``s' == s``. Any shift gives the same distribution up to rounding as long as
    the exponents stay inside ``[MIN_EXPONENT, MAX_EXPONENT]``.
    """
    z = values - (column_max(values) if top is None else top)
    z *= inv_tau
    np.maximum(z, MIN_EXPONENT, out=z)
    np.minimum(z, MAX_EXPONENT, out=z)
    return np.exp(z, out=z)


def choose_columns(values: np.ndarray, inv_tau: np.ndarray, u: np.ndarray,
                   top: np.ndarray | None = None) -> np.ndarray:
    """Sample one action per column of ``values`` (k, n) by inverse CDF with uniforms ``u`` (n,).

    This is the single kernel both learners use, so their choices agree bit for bit. Rows are
    combined one by one: numpy's reductions along a short axis cost more than k ufunc calls, and
    this runs 250,000 times per training run. ``top``: see ``softmax_weights``.
    """
    if len(values) == 1:
        return np.zeros(values.shape[1], dtype=np.int64)
    cum = softmax_weights(values, inv_tau, top)
    prev = cum[0]
    for j in range(1, len(cum)):
        row = cum[j]
        row += prev  # running sums in place: cum[j] = w[0] + ... + w[j]
        prev = row
    # The chosen index is the number of partial sums below the threshold: pack each column's
    # (at most 8) comparisons into a byte and count its bits with a table.
    packed = np.packbits(cum[:-1] < u * prev, axis=0)[0]
    return _POPCOUNT.take(packed)


_POPCOUNT = np.array([bin(v).count("1") for v in range(256)], dtype=np.int64)


def policy_probabilities(values: np.ndarray, mask: np.ndarray, inv_tau: float) -> np.ndarray:
    """P(a | s) of a row of action values under ``mask`` (zeros where not allowed)."""
    allowed = np.flatnonzero(mask)
    w = softmax_weights(np.asarray(values, dtype=float)[allowed][:, None], np.array([inv_tau]))[:, 0]
    probs = np.zeros(len(mask))
    probs[allowed] = w / w.sum()
    return probs


def column_max(values: np.ndarray) -> np.ndarray:
    """Maximum of each column of ``values`` (k, n), row by row (see ``softmax_weights``)."""
    top = values[0]
    for j in range(1, len(values)):
        top = np.maximum(top, values[j])
    return top


def expected_scores(p_success: np.ndarray, turns: int) -> tuple[float, float]:
    """Expected episode score of the best policy and of the uniform random policy, by dynamic programming.

    The best policy may depend on the turn number (finite horizon, no discount), so it bounds what
    any stationary learner over these states can reach; uniform random play is the floor. Both
    follow the episode model of ``core.mdp`` exactly (the outcome of the turn in ``s`` is unknown
    when choosing in ``s``).
    """
    p = np.asarray(p_success, dtype=float)
    if p.shape != (mdp.N_TURN_STATES,):
        raise ValueError(f"p_success must have shape (108,), got {p.shape}")
    p_turn = np.append(p, 0.0)  # START: its "outcome" does not matter (NEXT_STATE equal for both)
    immediate = p * mdp.SCORE[:, 1] + (1 - p) * mdp.SCORE[:, 0]  # expected eq.-(1) score of a turn in s'
    nxt = np.where(mdp.NEXT_STATE < 0, 0, mdp.NEXT_STATE)
    weights = np.stack([1 - p_turn, p_turn], axis=-1)[:, None, :]  # (109, 1, 2)
    best = np.zeros(mdp.N_STATES)
    rand = np.zeros(mdp.N_STATES)
    for _ in range(turns):
        q_best = (weights * (immediate[nxt] + best[nxt])).sum(axis=-1)
        q_rand = (weights * (immediate[nxt] + rand[nxt])).sum(axis=-1)
        best = np.where(mdp.ACTION_MASK, q_best, -np.inf).max(axis=1)
        rand = np.where(mdp.ACTION_MASK, q_rand, 0.0).sum(axis=1) / mdp.ACTION_MASK.sum(axis=1)
    return float(best[mdp.START]), float(rand[mdp.START])


# ----------------------------------------------------------------------------------------------
# One agent
# ----------------------------------------------------------------------------------------------


@dataclass
class QLearner:
    """One Q-learning agent over ``core.mdp`` (109 states x 6 actions).

    ``q`` (109, 6) action values, ``h`` (109, 6) engagement model, ``h_counts`` (109, 6) engagement
    observations per pair, ``visits`` (109,) times the agent acted (and learned) in each state.
    ``act`` samples from the softmax at the state's current temperature; ``update`` applies one
    transition. The maths is documented in the module docstring.
    """

    method: str = "performance"
    config: QConfig = field(default_factory=QConfig)
    q: np.ndarray | None = None
    h: np.ndarray | None = None
    h_counts: np.ndarray | None = None
    visits: np.ndarray | None = None
    process: str = "paper"  # the decision process (core.processes): its states index the tables

    def __post_init__(self) -> None:
        check_method(self.method)
        self._proc = processes.get(self.process)
        n_states = self._proc.n_states
        shape = (n_states, mdp.N_ACTIONS)
        self.q = _table(self.q, shape, 0.0, float, "q")
        self.h = _table(self.h, shape, self.config.h_prior, float, "h")
        self.h_counts = _table(self.h_counts, shape, 0, np.int64, "h_counts")
        self.visits = _table(self.visits, (n_states,), 0, np.int64, "visits")
        if np.any(self.h_counts < 0) or np.any(self.visits < 0):
            raise ValueError("h_counts and visits must be >= 0")
        # (next_state, max Q(next_state)) from the last update: the softmax shift of the next choice,
        # exactly as BatchLearner reuses it. Transient (not saved): any shift near the max is valid.
        self._shift: tuple[int, float] | None = None

    def values(self, state: int) -> np.ndarray:
        """The action values the agent chooses on: ``Q`` or, for ``qaug``, ``Q + beta2 * H``."""
        if self.method == "qaug":
            return self.q[state] + self.config.beta2 * self.h[state]
        return self.q[state].copy()

    def inverse_temperature(self, state: int) -> float:
        return float(inverse_temperature(self.visits[state], self.config))

    def probabilities(self, state: int) -> np.ndarray:
        """The current policy P(a | state) (zero for actions not allowed)."""
        self._check_state(state)
        return policy_probabilities(self.values(state), self._proc.action_mask[state], self.inverse_temperature(state))

    def choose(self, state: int, u: float) -> int:
        """The action for uniform ``u`` in [0, 1) (inverse CDF over the allowed actions)."""
        self._check_state(state)
        allowed = np.flatnonzero(self._proc.action_mask[state])
        column = self.values(state)[allowed][:, None]
        top = np.array([self._shift[1]]) if self._shift is not None and self._shift[0] == state else None
        k = choose_columns(column, np.array([self.inverse_temperature(state)]), np.array([u]), top)[0]
        return int(allowed[k])

    def act(self, state: int, rng: np.random.Generator) -> int:
        """Sample an allowed action for ``state`` with one uniform from ``rng``."""
        return self.choose(state, rng.random())

    def update(self, state: int, action: int, score: float, engagement: float | None,
               next_state: int, done: bool) -> float:
        """Learn from one transition; returns the TD target used."""
        self._check_state(state)
        if not self._proc.action_mask[state, action]:
            raise ValueError(f"action {mdp.ACTION_NAMES[action]} is not allowed in {self._proc.label(state)}")
        if not 0 <= next_state < self._proc.n_states or next_state == self._proc.start:
            raise ValueError(f"next_state must be a turn state 0..{self._proc.n_states - 1} other than "
                             f"START, got {next_state!r}")
        reward = float(score)
        if engagement is not None:
            e = float(engagement)
            if not np.isfinite(e):
                raise ValueError(f"engagement must be finite, got {engagement!r}")
            reward = reward + self.config.shaping_weight(self.method) * e
        if done:
            target, self._shift = reward, None
        else:
            best_next = self.q[next_state].max()
            target, self._shift = reward + self.config.gamma * best_next, (next_state, best_next)
        q_sa = self.q[state, action]
        self.q[state, action] = q_sa + self.config.alpha * (target - q_sa)
        if engagement is not None:
            n = self.h_counts[state, action] + 1
            self.h_counts[state, action] = n
            h_sa = self.h[state, action]
            self.h[state, action] = h_sa + (e - h_sa) / n
        self.visits[state] += 1
        return target

    #: The tables that are the agent's lasting state (saved in policy and participant files, in this order).
    TABLES = ("q", "h", "h_counts", "visits")

    def state_dict(self, transient: bool = False) -> dict[str, Any]:
        """The agent's state as JSON-ready lists: the ``TABLES``; with ``transient`` also the softmax
        shift of the next choice (``shift``), which a session checkpoint carries so that a resumed
        session draws exactly the actions the uninterrupted one would."""
        out: dict[str, Any] = {key: getattr(self, key).tolist() for key in self.TABLES}
        if transient:
            out["shift"] = list(self._shift) if self._shift is not None else None
        return out

    def load_state_dict(self, data: dict[str, Any]) -> None:
        """Put back a ``state_dict``: KeyError for a missing table, ValueError naming a table of the wrong
        shape or with non-finite values. Without ``shift`` the next choice starts unshifted."""
        if any(data[key] is None for key in self.TABLES):
            raise ValueError(f"{next(k for k in self.TABLES if data[k] is None)} is null")
        tables = {key: _table(data[key], getattr(self, key).shape, None, getattr(self, key).dtype.type, key)
                  for key in self.TABLES}
        for key, value in tables.items():
            setattr(self, key, value)
        shift = data.get("shift")
        self._shift = (int(shift[0]), float(shift[1])) if shift else None

    def _check_state(self, state: int) -> None:
        if not 0 <= state < self._proc.n_states:
            raise ValueError(f"state must be in 0..{self._proc.n_states - 1}, got {state!r}")


def _table(value, shape, fill, dtype, name) -> np.ndarray:
    if value is None:
        return np.full(shape, fill, dtype=dtype)
    arr = np.array(value, dtype=dtype)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite values")
    return arr
