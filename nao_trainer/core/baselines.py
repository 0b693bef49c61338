"""Baseline policies to compare the learned ones with, and trained learners that keep learning.

Pure: no I/O. Stationary baselines are probability tables (``core.evaluation`` evaluates them
exactly); the ones that depend on the history are ``core.evaluation.EpisodePolicy`` objects run by
Monte Carlo.

* ``fixed_level_policy(l)``: always level l (``core.evaluation``);
* ``best_fixed_level(p, e)``: the fixed level with the highest expected score on a user model;
* ``uniform_policy``: uniform over the allowed actions;
* ``core.evaluation.optimal``: the finite-horizon optimum (an oracle that knows the user's tables);
* ``Staircase("1u1d" | "2d1u" | "3d1u", start)``: level up after one success (``1u1d``), two
  (``2d1u``) or three (``3d1u``) successes in a row, down after one failure, starting at level
  ``start``; it only ever plays levels.
  It reacts to the outcome of the turn just played (its score, given to ``observe``) in either
  MDP, like the Bayes planner and QUEST+: no baseline sees an outcome later than the planner (the
  paper MDP's observed state carries it one turn late, which cost 3-down/1-up about 0.14 under
  target-p:0.75);
* ``learner_table(learner)``: a trained Q-learner frozen (its softmax at its current temperatures);
* ``KeepLearning(learner)``: the trained learner that goes on learning within each episode.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nao_trainer.core import processes
from nao_trainer.core.evaluation import evaluate, fixed_level_policy, uniform_policy
from nao_trainer.core.qlearning import QLearner, choose_columns, inverse_temperature, policy_probabilities

__all__ = ["fixed_level_policy", "uniform_policy", "best_fixed_level", "Staircase", "learner_table",
           "KeepLearning", "STAIRCASE_RULES"]

STAIRCASE_RULES: tuple[str, ...] = ("1u1d", "2d1u", "3d1u")
#: Successes in a row before a step up; the rule converges where P(up) = P(down): p^n = 1/2
#: (1u1d: 50 %, 2d1u: 70.7 %, 3d1u: 79.4 %; Levitt 1971, J. Acoust. Soc. Am. 49, 467).
STAIRCASE_UP_AFTER: dict[str, int] = {"1u1d": 1, "2d1u": 2, "3d1u": 3}


def best_fixed_level(p_success: np.ndarray, engagement: np.ndarray, turns: int = 25) -> int:
    """The level (1..4) whose fixed policy has the highest expected score (ties: the lower level)."""
    scores = [evaluate(fixed_level_policy(level), p_success, engagement, turns).score for level in (1, 2, 3, 4)]
    return int(np.argmax(np.round(scores, 12))) + 1


def staircase_step(level: np.ndarray, streak: np.ndarray, known: np.ndarray, need: int, top: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One step of an n-up/1-down rule on a ladder 1..top: ``known`` +1 success, -1 failure, 0 none."""
    streak = np.where(known > 0, streak + 1, np.where(known < 0, 0, streak))
    up = streak >= need
    down = known < 0
    return np.clip(level + up - down, 1, top), np.where(up, 0, streak)


def staircase_success_rate(rule: str, p_ladder: np.ndarray, turns: int, rng: np.random.Generator,
                           start: int = 1, walkers: int = 200) -> float:
    """Mean success rate of ``rule`` run for ``turns`` turns on a ladder whose step i succeeds with
    ``p_ladder[i-1]`` (outcomes seen straight away), over ``walkers`` independent runs; the first
    half of every run is discarded (the rule's convergence, not its approach)."""
    p = np.asarray(p_ladder, dtype=float)
    level = np.full(walkers, start)
    streak = np.zeros(walkers, dtype=np.int64)
    wins = 0.0
    for t in range(turns):
        success = rng.random(walkers) < p[level - 1]
        if t >= turns // 2:
            wins += success.sum()
        level, streak = staircase_step(level, streak, np.where(success, 1, -1), STAIRCASE_UP_AFTER[rule], len(p))
    return float(wins / (walkers * (turns - turns // 2)))


@dataclass
class Staircase:
    """An adaptive level rule (see the module docstring)."""

    rule: str = "1u1d"
    start: int = 2
    _level: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    _streak: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    _process: processes.DecisionProcess | None = field(default=None, repr=False)
    _last: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)

    def __post_init__(self) -> None:
        if self.rule not in STAIRCASE_RULES:
            raise ValueError(f"staircase rule must be one of {', '.join(STAIRCASE_RULES)}, got {self.rule!r}")
        if self.start not in (1, 2, 3, 4):
            raise ValueError(f"staircase start level must be 1..4, got {self.start!r}")

    @property
    def name(self) -> str:
        return f"staircase-{self.rule}@{self.start}"

    def reset(self, n: int, process: processes.DecisionProcess) -> None:
        self._level = np.full(n, self.start, dtype=np.int64)
        self._streak = np.zeros(n, dtype=np.int64)
        self._process = process
        self._last = np.zeros(n, dtype=np.int64)

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator) -> np.ndarray:
        known = self._last if turn > 0 else np.zeros(len(obs), dtype=np.int64)
        self._level, self._streak = staircase_step(self._level, self._streak, known, STAIRCASE_UP_AFTER[self.rule], 4)
        return self._level - 1

    def observe(self, obs: np.ndarray, action: np.ndarray, score: np.ndarray, *args) -> None:
        """The outcome of the turn just played: its score is positive on a success (equation (1))."""
        self._last = np.where(np.asarray(score) > 0, 1, -1).astype(np.int64)


def learner_table(learner: QLearner, process: "str | processes.DecisionProcess" = "paper") -> np.ndarray:
    """The frozen policy of a Q-learner: P(a | s) for every state (its softmax at its temperatures)."""
    proc = processes.get(process)
    if learner.q.shape[0] != proc.n_states:
        raise ValueError(f"the learner has {learner.q.shape[0]} states, the {proc.name} MDP {proc.n_states}")
    values = learner.q + (learner.config.beta2 * learner.h if learner.method == "qaug" else 0.0)
    inv = inverse_temperature(learner.visits, learner.config)
    return np.array([policy_probabilities(values[s], proc.action_mask[s], float(inv[s]))
                     for s in range(proc.n_states)])


class KeepLearning:
    """A trained learner that keeps learning during each evaluated episode (one copy per episode).

    Each episode starts from the trained tables and applies the training update after every turn
    (``core.qlearning``'s rule with the learner's method and hyper-parameters).
    """

    def __init__(self, learner: QLearner) -> None:
        self.learner = learner
        cfg = learner.config
        self._beta1 = cfg.shaping_weight(learner.method)
        self._beta2 = cfg.augment_weight(learner.method)

    def reset(self, n: int, process: processes.DecisionProcess) -> None:
        lr = self.learner
        if lr.q.shape[0] != process.n_states:
            raise ValueError(f"the learner has {lr.q.shape[0]} states, the {process.name} MDP {process.n_states}")
        self._mask = process.action_mask
        self.q = np.repeat(lr.q[None], n, axis=0)
        self.h = np.repeat(lr.h[None], n, axis=0)
        self.counts = np.repeat(lr.h_counts[None].astype(float), n, axis=0)
        self.visits = np.repeat(lr.visits[None], n, axis=0)
        self._rows = np.arange(n)

    def act(self, obs: np.ndarray, turn: int, rng: np.random.Generator) -> np.ndarray:
        r = self._rows
        values = self.q[r, obs] + self._beta2 * self.h[r, obs]  # (n, 6)
        values = np.where(self._mask[obs], values, -np.inf)
        inv = inverse_temperature(self.visits[r, obs], self.learner.config)
        return choose_columns(values.T.copy(), inv, rng.random(len(obs)))

    def observe(self, obs: np.ndarray, action: np.ndarray, score: np.ndarray, engagement: np.ndarray,
                next_obs: np.ndarray, done: bool) -> None:
        r, cfg = self._rows, self.learner.config
        target = score + self._beta1 * engagement
        if not done:
            target = target + cfg.gamma * self.q[r, next_obs].max(axis=1)
        q_sa = self.q[r, obs, action]
        self.q[r, obs, action] = q_sa + cfg.alpha * (target - q_sa)
        n = self.counts[r, obs, action] + 1
        self.counts[r, obs, action] = n
        h_sa = self.h[r, obs, action]
        self.h[r, obs, action] = h_sa + (engagement - h_sa) / n
        self.visits[r, obs] += 1
