"""Many Q-learners in lock-step over simulated users: the training engine of ``core.qlearning``'s maths.

Pure: no I/O. ``BatchLearner`` trains ``n`` independent agents (cluster x method x seed) with the
same learning rule, exploration and action sampling as ``core.qlearning.QLearner``; tests check
that both give identical actions and tables when fed the same random numbers. Two engines: the
vectorised numpy loop below, and the compiled kernel of ``core.qkernel`` (numba), bit-identical.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from nao_trainer.core import mdp, processes, qkernel
from nao_trainer.core.qlearning import QConfig, check_method, choose_columns, column_max, inverse_temperature

_N_LEVEL_ACTIONS = len(mdp.LEVEL_ACTIONS)


@dataclass
class BatchResult:
    """Final tables of every agent and its per-episode outcomes.

    ``episode_score[i, k]``: total eq.-(1) score of agent i's episode k; ``episode_engagement[i, k]``:
    that episode's mean per-turn engagement.
    """

    q: np.ndarray  # (n, 109, 6)
    h: np.ndarray  # (n, 109, 6)
    h_counts: np.ndarray  # (n, 109, 6)
    visits: np.ndarray  # (n, 109)
    episode_score: np.ndarray  # (n, episodes)
    episode_engagement: np.ndarray  # (n, episodes)


class BatchLearner:
    """``n`` independent Q-learners, each training on its own simulated user, stepped together.

    Agent ``i`` uses ``p_success[i]`` (108,) and ``engagement[i]`` (108, 2) of its simulated user,
    ``methods[i]`` and the shared ``config``. Each agent draws its random numbers from its own
    generator in blocks of ``(episodes, turns, 2)`` uniforms (``[..., 0]`` chooses the action,
    ``[..., 1]`` the outcome: success when ``u < p_success[s']``), so its result does not depend on
    the other agents in the batch nor on the block size.

    ``process``: the decision process (``core.processes``: ``paper`` or ``informed``); the agents' tables
    are over its observed states. ``engine``: ``numpy`` (all agents in lock-step, vectorised),
    ``numba`` (``core.qkernel``, one agent at a time, compiled) or ``auto`` (numba when installed).
    Both give the same tables for the same random numbers.

    In the numpy loop all agents start every episode in ``START`` at the same step, which makes the
    start-state mask a row slice. Per-agent tables are stored flat with the agent's offset added to
    the state index so every step is a handful of ``np.take`` calls over the agents. The full state
    of an agent is a *code* ``x = s * 2 + o`` (``core.processes``), stored with a stride of 218 per agent.
    """

    ENGINES = ("auto", "numpy", "numba")

    def __init__(self, p_success: np.ndarray, engagement: np.ndarray, methods: Sequence[str],
                 config: QConfig = QConfig(), process: str = "paper", engine: str = "numpy") -> None:
        p = np.asarray(p_success, dtype=float)
        e = np.asarray(engagement, dtype=float)
        n = len(methods)
        if p.shape != (n, mdp.N_TURN_STATES) or e.shape != (n, mdp.N_TURN_STATES, 2):
            raise ValueError(f"need p_success ({n}, 108) and engagement ({n}, 108, 2), got {p.shape} and {e.shape}")
        if not (np.all((p >= 0) & (p <= 1)) and np.all((e >= 0) & (e <= 1))):
            raise ValueError("p_success and engagement must lie in [0, 1]")
        if engine not in self.ENGINES:
            raise ValueError(f"engine must be one of {', '.join(self.ENGINES)}, got {engine!r}")
        self.methods = [check_method(m) for m in methods]
        self.config = config
        self.process = processes.get(process)
        self.engine = engine
        self.n = n
        self._p = p
        self._e = e

    def _local_tables(self) -> dict[str, np.ndarray]:
        """Per-code tables shared by all agents (codes 0..217, see the class docstring)."""
        C, A = 2 * mdp.N_STATES, mdp.N_ACTIONS
        nt = np.zeros((C, A), dtype=np.int64)
        nt[: processes.N_FULL] = 2 * np.where(processes.NEXT_TURN < 0, 0, processes.NEXT_TURN)
        obs = np.zeros(C, dtype=np.int64)
        obs[: processes.N_FULL] = self.process.obs
        score = np.zeros(C)
        score[: 2 * mdp.N_TURN_STATES] = mdp.SCORE.ravel()
        return {"nt": nt, "obs": obs, "score": score}

    def run(self, episodes: int, turns: int, rngs: Sequence[np.random.Generator], block: int = 200,
            progress: Callable[[int, int], None] | None = None) -> BatchResult:
        """Train every agent for ``episodes`` episodes of ``turns`` turns; ``progress(done, total)``."""
        if len(rngs) != self.n:
            raise ValueError(f"need one generator per agent ({self.n}), got {len(rngs)}")
        if episodes < 1 or turns < 1 or block < 1:
            raise ValueError(f"episodes, turns and block must be >= 1, got {episodes}, {turns}, {block}")
        engine = self.engine
        if engine == "auto":
            engine = "numba" if qkernel.available() else "numpy"
        if engine == "numba":
            return self._run_compiled(episodes, turns, rngs, progress)
        return self._run_numpy(episodes, turns, rngs, block, progress)

    def _agent_arrays(self, turns: int) -> dict[str, np.ndarray]:
        """Per-agent code tables (n, 218[, 6]) as the float operations of both engines use them."""
        cfg, n = self.config, self.n
        S = mdp.N_STATES
        loc = self._local_tables()
        e_g = np.zeros((n, S, 2))
        e_g[:, : mdp.N_TURN_STATES] = self._e
        e_g = e_g.reshape(n, 2 * S)
        p_g = np.zeros((n, S))
        p_g[:, : mdp.N_TURN_STATES] = self._p
        beta1 = np.array([cfg.shaping_weight(m) for m in self.methods])
        beta2 = np.array([cfg.augment_weight(m) for m in self.methods])
        reward = np.tile(loc["score"], (n, 1)) + beta1[:, None] * e_g  # r' = r + beta1 * e, as QLearner
        p_next = p_g[:, loc["nt"] // 2]  # (n, 218, 6)
        return {**loc, "e": e_g, "reward": reward, "p_next": p_next, "beta2": beta2}

    def _run_numpy(self, episodes: int, turns: int, rngs: Sequence[np.random.Generator], block: int,
                   progress: Callable[[int, int], None] | None) -> BatchResult:
        cfg, n = self.config, self.n
        S, A = self.process.n_states, mdp.N_ACTIONS
        C = 2 * mdp.N_STATES  # codes per agent
        NS = n * S
        agents = np.arange(n)
        gbase = agents * S  # global observed state gs = agent * S + state
        arr = self._agent_arrays(turns)
        cbase = agents * C  # global code gso = agent * C + code
        e_g = arr["e"].ravel()
        score_g = np.tile(arr["score"], n)
        reward_g = arr["reward"].ravel()
        beta2 = arr["beta2"]
        next_g = (arr["nt"][None] + cbase[:, None, None]).ravel()  # indexed by gso * A + a
        p_next = arr["p_next"].ravel()
        obs_g = (arr["obs"][None] + gbase[:, None]).ravel()  # global observed state of a global code
        inv_tau = inverse_temperature(np.arange(episodes * turns + 1), cfg)

        # Action-major tables (A, n * S): a column per global state makes max/softmax over actions
        # a few cheap ufunc calls on (n,) rows; flat index of (a, gs) is a * NS + gs.
        q = np.zeros((A, NS))
        h = np.full((A, NS), cfg.h_prior)
        qv = q + np.repeat(beta2, S)[None, :] * h  # values chosen on: Q or Q + beta2 * H
        counts = np.zeros((A, NS))  # float: (e - h) / n then matches QLearner's int count exactly
        visits = np.zeros(NS, dtype=np.int64)
        q_flat, h_flat, qv_flat, c_flat = q.ravel(), h.ravel(), qv.ravel(), counts.ravel()
        ep_score = np.zeros((n, episodes))
        ep_eng = np.zeros((n, episodes))
        start_gso = cbase + 2 * mdp.START if self.process.name == "paper" else cbase + self.process.start
        start_gs = gbase + self.process.start
        qv_start = qv[:_N_LEVEL_ACTIONS]
        alpha, gamma = cfg.alpha, cfg.gamma
        last = turns - 1

        for b0 in range(0, episodes, block):
            nb = min(block, episodes - b0)
            u = np.empty((nb, turns, 2, n))
            for i, rng in enumerate(rngs):
                u[..., i] = rng.random((nb, turns, 2))
            codes = np.empty((nb, turns, n), dtype=np.int64)
            for k in range(nb):
                gso, gs = start_gso, start_gs
                uk = u[k]
                top = None  # START: shift by the column max; later: max Q(s') of the last update
                for t in range(turns):
                    vis = visits[gs]
                    vals = (qv_start if t == 0 else qv).take(gs, axis=1)
                    ut = uk[t]
                    a = choose_columns(vals, inv_tau[vis], ut[0], top)
                    idx = gso * A + a
                    gso2 = next_g[idx] + (ut[1] < p_next[idx])
                    gs2 = obs_g[gso2]
                    codes[k, t] = gso2
                    target = reward_g[gso2]
                    if t != last:
                        top = column_max(q.take(gs2, axis=1))
                        target = target + gamma * top
                    qi = a * NS + gs
                    q_sa = q_flat[qi]
                    q_new = q_sa + alpha * (target - q_sa)
                    q_flat[qi] = q_new
                    cnt = c_flat[qi] + 1
                    c_flat[qi] = cnt
                    h_sa = h_flat[qi]
                    h_new = h_sa + (e_g[gso2] - h_sa) / cnt
                    h_flat[qi] = h_new
                    qv_flat[qi] = q_new + beta2 * h_new
                    visits[gs] = vis + 1
                    gso, gs = gso2, gs2
            # Per agent over its own contiguous (episode, turn) block, so the float sums do not
            # depend on how many agents share the batch.
            per_agent = np.ascontiguousarray(codes.transpose(2, 0, 1))
            ep_score[:, b0 : b0 + nb] = score_g[per_agent].sum(axis=2)
            ep_eng[:, b0 : b0 + nb] = e_g[per_agent].mean(axis=2)
            if progress is not None:
                progress(b0 + nb, episodes)
        as_agents = lambda x: np.ascontiguousarray(x.reshape(A, n, S).transpose(1, 2, 0))  # noqa: E731
        return BatchResult(
            q=as_agents(q), h=as_agents(h), h_counts=as_agents(counts).astype(np.int64),
            visits=visits.reshape(n, S), episode_score=ep_score, episode_engagement=ep_eng,
        )

    def _run_compiled(self, episodes: int, turns: int, rngs: Sequence[np.random.Generator],
                      progress: Callable[[int, int], None] | None) -> BatchResult:
        run_agent = qkernel.kernel()
        cfg, n = self.config, self.n
        S, A = self.process.n_states, mdp.N_ACTIONS
        arr = self._agent_arrays(turns)
        inv_tau = inverse_temperature(np.arange(episodes * turns + 1), cfg)
        nt = arr["nt"].ravel()
        start_code = 2 * mdp.START if self.process.name == "paper" else self.process.start
        out_q = np.zeros((n, S, A))
        out_h = np.zeros((n, S, A))
        out_c = np.zeros((n, S, A), dtype=np.int64)
        out_v = np.zeros((n, S), dtype=np.int64)
        ep_score = np.zeros((n, episodes))
        ep_eng = np.zeros((n, episodes))
        codes = np.empty((episodes, turns), dtype=np.int64)
        for i in range(n):
            u = rngs[i].random((episodes, turns, 2))
            q = np.zeros((A, S))
            h = np.full((A, S), cfg.h_prior)
            qv = q + arr["beta2"][i] * h
            counts = np.zeros((A, S))
            visits = np.zeros(S, dtype=np.int64)
            run_agent(u, nt, arr["p_next"][i].ravel(), arr["obs"], arr["reward"][i], arr["e"][i], inv_tau,
                      q, h, qv, counts, visits, float(arr["beta2"][i]), cfg.alpha, cfg.gamma,
                      self.process.start, start_code, _N_LEVEL_ACTIONS, codes)
            out_q[i], out_h[i], out_c[i], out_v[i] = q.T, h.T, counts.T.astype(np.int64), visits
            ep_score[i] = arr["score"][codes].sum(axis=1)
            ep_eng[i] = arr["e"][i][codes].mean(axis=1)
            if progress is not None:
                progress(episodes * (i + 1) // n, episodes)
        return BatchResult(q=out_q, h=out_h, h_counts=out_c, visits=out_v, episode_score=ep_score,
                           episode_engagement=ep_eng)
