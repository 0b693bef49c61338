"""Hyper-parameter sweeps: train learners at every point of a grid and score their final policies exactly.

A sweep specification is one or more ``NAME=START:STOP:COUNT`` (``COUNT`` evenly spaced values from
``START`` to ``STOP``) or ``NAME=V1,V2,...``; several parameters make a grid (every combination).
``NAME`` is a ``core.qlearning.QConfig`` field. The whole specification is checked, and every
point's ``QConfig`` built, before any work starts.

At each (point, user) ``seeds`` learners of ``method`` are trained on the user's training simulator
(seeds shared by all points: common random numbers make neighbouring points comparable), then
each final policy, frozen, is evaluated exactly on the user's true tables. Work items are
(point, user) pairs fanned out through ``learn.parallel`` (local processes or a dask cluster);
results do not depend on where they ran.
"""
from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import baselines, evaluation
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import METHODS, QConfig, QLearner
from nao_trainer.errors import ConfigError
from nao_trainer.learn.parallel import fan_out
from nao_trainer.learn.users import User

PARAMETERS: tuple[str, ...] = tuple(QConfig.__dataclass_fields__)
MAX_POINTS = 1_000_000


def parse_param(text: str) -> tuple[str, list[float]]:
    """``NAME=START:STOP:COUNT`` or ``NAME=V1,V2,...`` -> (name, values); ConfigError otherwise."""
    name, eq, rest = str(text).partition("=")
    name = name.strip()
    if not eq or not rest.strip():
        raise ConfigError(f"--param {text!r}: use NAME=START:STOP:COUNT or NAME=V1,V2,... (NAME one of "
                          f"{', '.join(PARAMETERS)})")
    if name not in PARAMETERS:
        raise ConfigError(f"--param {text!r}: unknown parameter {name!r}; use one of {', '.join(PARAMETERS)}")
    try:
        if ":" in rest:
            parts = rest.split(":")
            if len(parts) == 2:
                raise ConfigError(f"--param {text!r}: the COUNT is missing (NAME=START:STOP:COUNT, e.g. "
                                  f"{name}={parts[0]}:{parts[1]}:11 for 11 values from {parts[0]} to {parts[1]})")
            if len(parts) != 3:
                raise ValueError
            start, stop, count_text = float(parts[0]), float(parts[1]), parts[2].strip()
            count = int(count_text)
            if count < 0:
                raise ConfigError(f"--param {text!r}: negative count {count}")
            if count == 0 or stop < start or (count > 1 and stop == start):
                raise ConfigError(f"--param {text!r}: empty range (need START < STOP and COUNT >= 1, or COUNT = 1)")
            values = np.linspace(start, stop, count).tolist()
        else:
            values = [float(v) for v in rest.split(",") if v.strip()]
            if not values:
                raise ConfigError(f"--param {text!r}: empty list of values")
    except ValueError:
        raise ConfigError(f"--param {text!r}: values must be numbers (NAME=START:STOP:COUNT or NAME=V1,V2,...)") from None
    if not all(np.isfinite(values)):
        raise ConfigError(f"--param {text!r}: values must be finite")
    return name, values


@dataclass(frozen=True)
class SweepSpec:
    params: tuple[tuple[str, tuple[float, ...]], ...]
    method: str = "performance"
    seeds: int = 20
    episodes: int = 10_000
    turns: int = 25
    seed: int = 0
    process: str = "paper"
    base: QConfig = field(default_factory=QConfig)

    def points(self) -> list[dict[str, float]]:
        names = [n for n, _ in self.params]
        return [dict(zip(names, combo)) for combo in itertools.product(*(v for _, v in self.params))]


def make_spec(param_texts: Sequence[str], method: str | None = None, seeds: int = 20, episodes: int = 10_000,
              turns: int = 25, seed: int = 0, process: str = "paper") -> SweepSpec:
    """A checked sweep specification (every point's QConfig is built here); ConfigError otherwise."""
    if not param_texts:
        raise ConfigError("--param: give at least one NAME=START:STOP:COUNT")
    params = [parse_param(t) for t in param_texts]
    names = [n for n, _ in params]
    if len(set(names)) != len(names):
        raise ConfigError(f"--param: each parameter once, got {', '.join(names)}")
    if method is None:
        method = "shaping" if "beta1" in names else "qaug" if "beta2" in names else "performance"
    if method not in METHODS:
        raise ConfigError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    for name, low in (("seeds", 1), ("episodes", 1), ("turns", 1)):
        value = {"seeds": seeds, "episodes": episodes, "turns": turns}[name]
        if value < low:
            raise ConfigError(f"--{name} must be >= {low}, got {value}")
    spec = SweepSpec(tuple((n, tuple(v)) for n, v in params), method, seeds, episodes, turns, seed, process)
    n_points = int(np.prod([len(v) for _, v in params]))
    if n_points > MAX_POINTS:
        raise ConfigError(f"--param: {n_points} grid points are more than {MAX_POINTS}")
    for point in spec.points():
        try:
            replace(spec.base, **point)
        except ValueError as exc:
            raise ConfigError(f"--param: the point {point} is not a valid setting ({exc})") from None
    return spec


def _user_key(name: str) -> int:
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def run_point(spec: SweepSpec, point: dict[str, float], user: User) -> dict[str, Any]:
    """Train ``spec.seeds`` learners at one point on one user; exact scores of their frozen policies."""
    config = replace(spec.base, **point)
    sim = user.train
    n = spec.seeds
    rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(spec.seed, spawn_key=(_user_key(user.name), k))))
            for k in range(n)]
    res = BatchLearner(np.stack([sim.p_success] * n), np.stack([sim.engagement] * n), [spec.method] * n, config,
                       spec.process, "auto").run(spec.episodes, spec.turns, rngs)
    scores, engagement = [], []
    for k in range(n):
        lr = QLearner(spec.method, config, res.q[k], res.h[k], res.h_counts[k], res.visits[k], spec.process)
        out = evaluation.evaluate(baselines.learner_table(lr, spec.process), user.truth.p_success,
                                  user.truth.engagement, spec.turns, spec.process)
        scores.append(out.score)
        engagement.append(out.engagement)
    tail = max(1, spec.episodes // 10)
    scores_a = np.array(scores)
    ci = evaluation.t_interval(scores_a)
    return {"user": user.name, **point, "method": spec.method, "scores": scores, "score": float(scores_a.mean()),
            "score_ci": None if ci is None else list(ci), "engagement": float(np.mean(engagement)),
            "training_tail_score": float(res.episode_score[:, -tail:].mean())}


def run(spec: SweepSpec, users: Sequence[User], workers: int = 2, backend: str | None = None) -> list[dict[str, Any]]:
    """Every (point, user) result, in grid order (points outer, users inner)."""
    tasks = [(spec, point, user) for point in spec.points() for user in users]
    return fan_out(run_point, tasks, workers, backend, progress="sweep: (point, user) runs")
