"""Training user-specific policies on simulated users (paper section 5.2, Figures 7 and 8).

``train_grid`` trains one Q-learner per (cluster, method, seed) with ``core.batch.BatchLearner``,
split over worker processes, and summarises the runs; ``write_outputs`` writes the figures, CSV
tables, ``results.json`` and one policy file per (cluster, method) (format: ``nao_trainer.learn.policy_files``).

Reproducibility: agent (cluster, method, seed index) draws from
``SeedSequence(base_seed, spawn_key=(cluster_key, method_index, seed_index))`` where
``cluster_key`` is derived from the cluster id's text, so an agent's run is the same whatever
else is trained with it, in whichever process.

Summary statistics (``results``): ``optimal_score`` / ``random_score`` are the expected episode
scores of the best and of uniform random play on the cluster's simulator (dynamic programming,
``core.qlearning.expected_scores``), for scale. For each agent, its mean per-episode score (sum of eq. (1) over
the episode's turns) and mean per-episode engagement (mean over the turns) over the *last 10 %*
of episodes (``tail``); ``score_mean`` is the mean of that over seeds and ``score_ci`` the 95 %
t-interval of the mean over seeds (``None`` with one seed). Rows of other methods add
``vs_performance``: their difference to the performance-only learner in final score and
engagement with a 95 % Welch interval and whether it excludes 0. Learning curves are the per-episode
means over seeds with the same per-episode 95 % t-interval.
"""
from __future__ import annotations

import gzip
import hashlib
import io
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.core import distributions, evaluation, mdp, processes
from nao_trainer.core.batch import BatchLearner
from nao_trainer.core.qlearning import METHODS, QConfig, QLearner, expected_scores
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import raise_if_interrupted
from nao_trainer.files import write_json_atomic, write_text_atomic
from nao_trainer.learn import policy_files
from nao_trainer.learn.parallel import check_backend, fan_out


@dataclass(frozen=True)
class TrainingSpec:
    """What to train: every (cluster, method, seed) for ``episodes`` episodes of ``turns`` turns."""

    methods: tuple[str, ...] = METHODS
    seeds: int = 20
    episodes: int = 10_000
    turns: int = 25
    seed: int = 0
    workers: int = 2
    config: QConfig = field(default_factory=QConfig)
    tail: float = 0.1  # fraction of final episodes summarised
    block: int = 200  # episodes of random numbers drawn per agent at a time (speed only)
    process: str = "paper"  # the decision process (core.processes): paper or informed
    engine: str = "auto"  # numpy, numba or auto (numba when installed); same results
    backend: str | None = None  # None: local processes; dask://HOST:PORT: a dask.distributed cluster

    def __post_init__(self) -> None:
        try:
            processes.get(self.process)
        except ValueError:
            raise ValueError(f"mdp must be one of {', '.join(processes.NAMES)}, got {self.process!r}") from None
        if self.engine not in BatchLearner.ENGINES:
            raise ValueError(f"engine must be one of {', '.join(BatchLearner.ENGINES)}, got {self.engine!r}")
        check_backend(self.backend)
        # Messages start with the field's name (the CLI prefixes "--" to name its option).
        if not self.methods:
            raise ValueError("methods: give at least one of " + ", ".join(METHODS))
        for m in self.methods:
            if m not in METHODS:
                raise ValueError(f"methods: unknown method {m!r} (each method must be one of {', '.join(METHODS)})")
        if len(set(self.methods)) != len(self.methods):
            raise ValueError(f"methods: each method once, got {', '.join(self.methods)}")
        for name, low in (("seeds", 1), ("episodes", 1), ("turns", 1), ("workers", 1), ("block", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not 0 < self.tail <= 1:
            raise ValueError(f"tail must be in (0, 1], got {self.tail!r}")

    @property
    def tail_episodes(self) -> int:
        return max(1, int(round(self.episodes * self.tail)))


@dataclass(frozen=True)
class Agent:
    cluster: str
    method: str
    seed_index: int


def cluster_key(cluster: str) -> int:
    """A stable 32-bit integer for a cluster id (part of every agent's seed)."""
    return int.from_bytes(hashlib.sha256(str(cluster).encode()).digest()[:4], "little")


def agent_seed(base_seed: int, agent: Agent) -> np.random.SeedSequence:
    """The seed sequence of one agent: independent of the batch it is trained in."""
    key = (cluster_key(agent.cluster), METHODS.index(agent.method), agent.seed_index)
    return np.random.SeedSequence(base_seed, spawn_key=key)


@dataclass
class GridResult:
    """Everything a training run produced. Arrays are indexed [cluster, method, seed, ...]."""

    spec: TrainingSpec
    clusters: list[str]
    simulators: list[UserSimulator]
    episode_score: np.ndarray  # (C, M, seeds, episodes)
    episode_engagement: np.ndarray  # (C, M, seeds, episodes)
    q: np.ndarray  # (C, M, seeds, 109, 6)
    h: np.ndarray
    h_counts: np.ndarray
    visits: np.ndarray  # (C, M, seeds, 109)
    seconds: float

    @property
    def turns(self) -> int:
        """Simulated turns in the whole run."""
        return int(self.episode_score.size * self.spec.turns)

    def learner(self, c: int, m: int, k: int) -> QLearner:
        return QLearner(self.spec.methods[m], self.spec.config, self.q[c, m, k].copy(), self.h[c, m, k].copy(),
                        self.h_counts[c, m, k].copy(), self.visits[c, m, k].copy(), self.spec.process)

    # -- summaries ------------------------------------------------------------------------------

    def tail_means(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-agent mean episode score and engagement over the last ``tail`` episodes (C, M, seeds)."""
        n = self.spec.tail_episodes
        return self.episode_score[..., -n:].mean(axis=-1), self.episode_engagement[..., -n:].mean(axis=-1)

    def representative_seed(self, c: int, m: int) -> int:
        """The seed whose final score is closest to the median over seeds (the one shipped)."""
        scores = self.tail_means()[0][c, m]
        return int(np.argmin(np.abs(scores - np.median(scores))))

    def results(self) -> list[dict[str, Any]]:
        """One row per (cluster, method); see the module docstring for the definitions."""
        score, eng = self.tail_means()
        probs = self.s0_probabilities()
        rows = []
        for c, cluster in enumerate(self.clusters):
            best, uniform = self._scale(c)
            for m, method in enumerate(self.spec.methods):
                s_mean, s_ci = mean_ci(score[c, m])
                e_mean, e_ci = mean_ci(eng[c, m])
                rows.append({
                    "cluster": cluster,
                    "method": method,
                    "score_mean": s_mean,
                    "score_ci": s_ci,
                    "engagement_mean": e_mean,
                    "engagement_ci": e_ci,
                    "seeds": self.spec.seeds,
                    "tail_episodes": self.spec.tail_episodes,
                    "first_score_mean": float(self.episode_score[c, m, :, : self.spec.tail_episodes].mean()),
                    "first_engagement_mean": float(self.episode_engagement[c, m, :, : self.spec.tail_episodes].mean()),
                    "optimal_score": round(best, 4),
                    "random_score": round(uniform, 4),
                    "s0_probabilities": dict(zip(mdp.ACTION_NAMES, probs[c, m].round(6).tolist())),
                    "policy_seed": self.representative_seed(c, m),
                })
                if method != "performance" and "performance" in self.spec.methods:
                    base = self.spec.methods.index("performance")
                    rows[-1]["vs_performance"] = {
                        "score_diff": diff_ci(score[c, m], score[c, base]),
                        "engagement_diff": diff_ci(eng[c, m], eng[c, base]),
                    }
        return rows

    def _scale(self, c: int) -> tuple[float, float]:
        """Expected score of the optimum and of uniform play on cluster c's simulator, in this MDP."""
        if self.spec.process == "paper":
            return expected_scores(self.simulators[c].p_success, self.spec.turns)
        sim = self.simulators[c]
        best = evaluation.optimal(sim.p_success, self.spec.turns, self.spec.process).value
        uniform = evaluation.evaluate(evaluation.uniform_policy(self.spec.process), sim.p_success, sim.engagement,
                                      self.spec.turns, self.spec.process).score
        return best, uniform

    @property
    def s0_index(self) -> int:
        """S0 in this MDP: in the informed MDP, S0 after its failed turn (the paper's S0 follows a failure)."""
        return mdp.S0_INDEX if self.spec.process == "paper" else 2 * mdp.S0_INDEX

    def s0_probabilities(self, state: int | None = None) -> np.ndarray:
        """Mean over seeds of each agent's final P(a | state) (C, M, 6); qaug uses Q' (Figure 8).

        The default state is S0; in the informed MDP S0 after a failure (the paper's S0 follows a
        failed level-2 turn).
        """
        state = self.s0_index if state is None else state
        C, M, K = self.q.shape[:3]
        out = np.zeros((C, M, mdp.N_ACTIONS))
        for c in range(C):
            for m in range(M):
                out[c, m] = np.mean([self.learner(c, m, k).probabilities(state) for k in range(K)], axis=0)
        return out

    def curves(self) -> dict[str, np.ndarray]:
        """Per-episode mean over seeds and 95 % t-interval: keys ``score``/``engagement`` x ``mean/lo/hi``."""
        out = {}
        for name, data in (("score", self.episode_score), ("engagement", self.episode_engagement)):
            mean = data.mean(axis=2)
            half = _t_half_width(data, axis=2)
            out[f"{name}_mean"], out[f"{name}_lo"], out[f"{name}_hi"] = mean, mean - half, mean + half
        return out

    def summary_json(self) -> dict[str, Any]:
        return {"results": self.results(), "turns": self.turns, "seconds": round(self.seconds, 3)}


def mean_ci(values: np.ndarray) -> tuple[float, list[float] | None]:
    """Mean and 95 % t-interval of the mean (None for a single value)."""
    values = np.asarray(values, dtype=float)
    mean = float(values.mean())
    if values.size < 2:
        return mean, None
    half = float(_t_half_width(values[None, :], axis=1)[0])
    return mean, [mean - half, mean + half]


def diff_ci(a: np.ndarray, b: np.ndarray) -> dict[str, Any]:
    """Difference of means ``a - b`` over seeds with its 95 % Welch interval (None below 2 seeds each)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    diff = float(a.mean() - b.mean())
    if a.size < 2 or b.size < 2:
        return {"diff": diff, "ci": None, "significant": None}
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    if se == 0:
        return {"diff": diff, "ci": [diff, diff], "significant": diff != 0}
    dof = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = float(distributions.t_ppf(0.975, dof) * se)
    return {"diff": diff, "ci": [diff - half, diff + half], "significant": bool(abs(diff) > half)}


def _t_half_width(data: np.ndarray, axis: int) -> np.ndarray:
    n = data.shape[axis]
    if n < 2:
        return np.zeros(np.delete(data.shape, axis))
    return distributions.t_ppf(0.975, n - 1) * data.std(axis=axis, ddof=1) / math.sqrt(n)


# ----------------------------------------------------------------------------------------------
# Running the grid
# ----------------------------------------------------------------------------------------------


def _run_chunk(p: np.ndarray, e: np.ndarray, methods: list[str], config: QConfig,
               seeds: list[np.random.SeedSequence], episodes: int, turns: int, block: int,
               report: bool, process: str = "paper", engine: str = "numpy") -> tuple[Any, float]:
    """Train one chunk of agents (runs in a worker process or in-process)."""
    rngs = [np.random.Generator(np.random.PCG64(s)) for s in seeds]
    t0 = time.perf_counter()
    last = [t0]

    def progress(done: int, total: int) -> None:
        raise_if_interrupted()  # a Ctrl-C that a library swallowed
        now = time.perf_counter()
        if report and (now - last[0] >= 2.0 or done == total):
            last[0] = now
            rate = done * turns * len(methods) / max(now - t0, 1e-9)
            print(f"  train: episode {done}/{total} ({rate / 1e6:.2f} M turns/s in this worker)",
                  file=sys.stderr, flush=True)

    result = BatchLearner(p, e, methods, config, process, engine).run(episodes, turns, rngs, block=block,
                                                                       progress=progress)
    return result, time.perf_counter() - t0


def train_grid(simulators: Sequence[UserSimulator], clusters: Sequence[str], spec: TrainingSpec,
               progress: bool = True) -> GridResult:
    """Train every (cluster, method, seed) agent of ``spec`` on its cluster's simulator."""
    if len(simulators) != len(clusters) or not clusters:
        raise ValueError("need one simulator per cluster id (and at least one)")
    if len(set(clusters)) != len(clusters):
        raise ValueError(f"cluster ids must be distinct, got {list(clusters)}")
    agents = [Agent(c, m, k) for c in clusters for m in spec.methods for k in range(spec.seeds)]
    sim_of = dict(zip(clusters, simulators))
    p = np.stack([sim_of[a.cluster].p_success for a in agents])
    e = np.stack([sim_of[a.cluster].engagement for a in agents])
    methods = [a.method for a in agents]
    seeds = [agent_seed(spec.seed, a) for a in agents]
    n_workers = max(1, min(spec.workers, len(agents)))
    bounds = np.linspace(0, len(agents), n_workers + 1).round().astype(int)
    chunks = [(p[a:b], e[a:b], methods[a:b], spec.config, seeds[a:b], spec.episodes, spec.turns, spec.block,
               progress and i == 0, spec.process, spec.engine) for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]
    if progress:
        total = len(agents) * spec.episodes * spec.turns
        print(f"train: {len(clusters)} clusters x {len(spec.methods)} methods x {spec.seeds} seeds = {len(agents)} "
              f"agents, {spec.episodes} episodes x {spec.turns} turns ({total / 1e6:.1f} M turns) "
              f"on {n_workers} worker(s)", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    outputs = fan_out(_run_chunk, chunks, n_workers, spec.backend)
    seconds = time.perf_counter() - t0
    parts = [o[0] for o in outputs]
    shape = (len(clusters), len(spec.methods), spec.seeds)

    def gather(attr: str) -> np.ndarray:
        data = np.concatenate([getattr(r, attr) for r in parts])
        return data.reshape(shape + data.shape[1:])

    return GridResult(
        spec=spec, clusters=list(clusters), simulators=list(simulators),
        episode_score=gather("episode_score"), episode_engagement=gather("episode_engagement"),
        q=gather("q"), h=gather("h"), h_counts=gather("h_counts"), visits=gather("visits"), seconds=seconds,
    )


# ----------------------------------------------------------------------------------------------
# Outputs
# ----------------------------------------------------------------------------------------------

CURVES_CSV = "learning_curves.csv.gz"  # gzip: 90,000 rows for the full grid
S0_CSV = "s0_action_probabilities.csv"
RESULTS_JSON = "results.json"
FIGURE7 = "figure7_learning_curves.png"
FIGURE8 = "figure8_s0_policies.png"


def write_curves_csv(result: GridResult, path: Path) -> None:
    """Per-episode means over seeds and 95 % bands, one row per (cluster, method, episode)."""
    curves = result.curves()
    cols = ["score_mean", "score_lo", "score_hi", "engagement_mean", "engagement_lo", "engagement_hi"]
    episodes = np.arange(1, result.spec.episodes + 1)
    # mtime=0: the same run gives the same bytes; level 6 is much faster than the default 9, nearly as small.
    with gzip.GzipFile(path, "wb", compresslevel=6, mtime=0) as raw, io.TextIOWrapper(raw, encoding="utf-8") as fh:
        fh.write("cluster,method,episode," + ",".join(cols) + "\n")
        for c, cluster in enumerate(result.clusters):
            for m, method in enumerate(result.spec.methods):
                block = np.column_stack([curves[k][c, m] for k in cols])
                lines = [f"{cluster},{method},{ep}," + ",".join(f"{v:.5g}" for v in row)
                         for ep, row in zip(episodes, block)]
                fh.write("\n".join(lines) + "\n")


def write_s0_csv(result: GridResult, path: Path) -> None:
    """P(a | S0) per cluster and method (mean over seeds) and how often S0 was visited.

    A policy at a rarely visited state stays close to uniform: ``s0_visits_mean`` tells which.
    """
    probs = result.s0_probabilities()
    visits = result.visits[..., result.s0_index].mean(axis=2)
    lines = ["cluster,method," + ",".join(mdp.ACTION_NAMES) + ",s0_visits_mean"]
    for c, cluster in enumerate(result.clusters):
        for m, method in enumerate(result.spec.methods):
            lines.append(f"{cluster},{method}," + ",".join(f"{v:.6f}" for v in probs[c, m]) + f",{visits[c, m]:.1f}")
    write_text_atomic(path, "\n".join(lines) + "\n")


def default_methods(result: GridResult) -> dict[str, str]:
    """Per cluster, the method whose policies reached the highest final score (engagement breaks ties)."""
    score, eng = result.tail_means()
    out = {}
    for c, cluster in enumerate(result.clusters):
        key = [(round(float(score[c, m].mean()), 9), float(eng[c, m].mean())) for m in range(len(result.spec.methods))]
        out[cluster] = result.spec.methods[max(range(len(key)), key=key.__getitem__)]
    return out


def write_outputs(result: GridResult, out_dir: Path, models_source: str, command: str) -> dict[str, Path]:
    """Write curves, S0 probabilities, results.json, policies and their manifest to ``out_dir``.

    The figures are the command's business: ``plots.learning.write_figures(result, out_dir)``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"curves": out / CURVES_CSV, "s0": out / S0_CSV, "results": out / RESULTS_JSON}
    write_curves_csv(result, paths["curves"])
    write_s0_csv(result, paths["s0"])
    written: dict[str, str] = {}
    for c, cluster in enumerate(result.clusters):
        for m, method in enumerate(result.spec.methods):
            k = result.representative_seed(c, m)
            score, eng = (float(x[c, m, k]) for x in result.tail_means())
            provenance = {
                "base_seed": result.spec.seed, "seed_index": k, "seeds_trained": result.spec.seeds,
                "episodes": result.spec.episodes, "turns": result.spec.turns, "models": models_source,
                "command": command, "tail_score_mean": score, "tail_engagement_mean": eng,
                "selection": "seed whose final score is closest to the median over seeds",
            }
            path = out / policy_files.policy_filename(cluster, method)
            policy_files.save_policy_file(path, policy_files.make_payload(result.learner(c, m, k), cluster,
                                                                          result.simulators[c], provenance))
            written[f"{cluster}:{method}"] = path.name
    summary = result.summary_json()
    summary["default_method"] = default_methods(result)
    summary["spec"] = {"methods": list(result.spec.methods), "seeds": result.spec.seeds, "mdp": result.spec.process,
                       "episodes": result.spec.episodes, "turns": result.spec.turns, "seed": result.spec.seed,
                       "hyperparameters": result.spec.config.to_dict(), "models": models_source,
                       "command": command}
    summary["policies"] = written
    summary["simulators"] = {cl: {"name": s.name, "fingerprint": s.fingerprint()}
                             for cl, s in zip(result.clusters, result.simulators)}
    write_json_atomic(paths["results"], summary)
    policy_files.write_manifest(out, {cl: result.spec.methods for cl in result.clusters}, summary["default_method"],
                                written)
    return paths
