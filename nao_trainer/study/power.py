"""``study power``: the power of the pre-registered test, by simulating the whole study many times.

One simulated study of N participants: N users drawn with replacement from a user set
(``learn.users``: by default one user per real session of the published data, success shrunk toward
its cluster; for a protocol of a task the published data are not of, e.g. n-back, the task's own
simulated users, ``learn.users.task_user_set``, which the personalised and bayes arms also take as
their user models and prior), allocated to the arms by blocked randomisation as the protocol says, each playing the
protocol's sessions with its arm's policy. Every session is a simulated episode of ``session.turns``
turns (``core.processes`` transitions, success drawn per turn), so the turn-to-turn randomness of a real
session is in the outcomes; on top of it, a participant's ability moves from session to session
(``drift``: a shift of every level's success probability on the logit scale, N(0, drift^2), drawn per
participant and session; 0.3 by default, an assumption: the published data hold too few repeated
sessions of one person to estimate it).

Policies: every arm plays its policy's own offline form, declared by the policy plug-in and found
through the registry (``policies.factory.offline_policy``): ``schedule`` and ``random`` exactly as the
live ones choose; ``usp:C`` as its trained table (no learning within the simulated sessions);
``personalised`` as ``core.assessment.Personaliser`` with the shipped user models and policies, the
assessment in session 1 and the posterior carried to the next session (its candidate learners do not
keep learning: the live policy's small in-session updates are left out); ``bayes`` as its solved plan
in session 1, then the posterior-best level after the carried counts (``policies.bayes.BayesSessions``:
a later live session re-solves the plan per participant, out of reach here). The shipped models were
fitted on all 50 sessions, the users included, which favours the personalised and bayes arms: their
power is an upper bound.

The test: the protocol's model ``outcome ~ arm + session + (1|participant)`` with arm-specific
residual variances (``study.analysis``: participants in different arms vary differently; the random
arm's SD of participant means is 12.3 points, level 2's 7.1), each arm against the reference arm
by a t test with Satterthwaite's degrees of freedom. With every participant playing the same
sessions (balanced), the estimate of an arm effect is the difference of the arms' means of
participant means, its variance ``s_a^2/n_a + s_ref^2/n_ref`` from the two arms' own variances of
those means (Welch), the reference distribution t with Satterthwaite's df: that closed form is
used here (thousands of fits per second) and is what ``study analyse`` computes on the real data.
(The former test pooled one variance over all arms and used the normal reference: a 3-arm null
with unequal variances rejected 1.3-2 % instead of 5 %, and 7.7 % at N = 12.)

Multiplicity: the protocol names the primary outcome and the primary contrast
(``analysis.primary_contrast`` against ``analysis.reference_arm``), tested at alpha; every other
outcome and contrast is adjusted by Holm's step-down procedure in ``study analyse``, so its power
here, unadjusted, is an upper bound.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from nao_trainer.core import distributions, evaluation, mdp, processes
from nao_trainer.errors import ConfigError
from nao_trainer.files import write_json_atomic, write_text_atomic
from nao_trainer.policies.factory import offline_policy
from nao_trainer.study.protocol import SIMULATED_OUTCOMES, Arm, Protocol

Z80 = 0.8416212335729143  # standard normal quantile of 0.8


class SessionPolicies:
    """The arm's policy for a batch of ``n`` participants, session after session: the policy's own offline
    form, found through the registry (``policies.factory.offline_policy``), whatever its kind."""

    def __init__(self, protocol: Protocol, arm: Arm) -> None:
        config = protocol.arm_config(arm)
        self.turns = config.session.turns
        self.kind = arm.policy
        self.offline = offline_policy(config.policy, self.turns, config.task.build_task())

    def start(self, n: int, session: int) -> Any:
        """The ``EpisodePolicy`` of session ``session`` (1-based) for the same ``n`` participants."""
        return self.offline.start(n, session)


def play_sessions(policy: Any, p: np.ndarray, e: np.ndarray, turns: int, rng: np.random.Generator) -> np.ndarray:
    """Episodes with one user per episode (``p`` (n, 108), ``e`` (n, 108, 2)): (n, 3) score, mean engagement,
    success rate (the columns of ``SIMULATED_OUTCOMES``)."""
    proc = processes.get("paper")
    n = len(p)
    rows = np.arange(n)
    full = np.full(n, processes.START_FULL)
    out = np.zeros((n, 3))
    for t in range(turns):
        obs = proc.obs[full]
        a = np.asarray(policy.act(obs, t, rng), dtype=np.int64)
        s2 = processes.NEXT_TURN[full, a]
        o2 = (rng.random(n) < p[rows, s2]).astype(np.int64)
        r = mdp.SCORE[s2, o2].astype(float)
        en = e[rows, s2, o2]
        out += np.column_stack([r, en, o2])
        full = s2 * 2 + o2
        policy.observe(obs, a, r, en, proc.obs[full], t == turns - 1)
    out[:, 1:] /= turns
    return out


def _drifted(p: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    if sd <= 0:
        return p
    logit = np.log(np.clip(p, 1e-4, 1 - 1e-4) / (1 - np.clip(p, 1e-4, 1 - 1e-4)))
    return 1.0 / (1.0 + np.exp(-(logit + rng.normal(0.0, sd, (len(p), 1)))))


def blocked_arms(protocol: Protocol, n: int, rng: np.random.Generator) -> np.ndarray:
    """Arm index of n participants by the protocol's blocked randomisation (strata ignored)."""
    rounds = protocol.allocation.block_size // sum(a.ratio for a in protocol.arms)
    block = np.array([i for i, a in enumerate(protocol.arms) for _ in range(a.ratio * rounds)])
    return np.concatenate([block[rng.permutation(len(block))] for _ in range(-(-n // len(block)))])[:n]


@dataclass
class PowerReport:
    name: str
    protocol_sha256: str
    ns: list[int]
    reps: int
    alpha: float
    users: str
    drift: float
    power: dict[str, list[float]] = field(default_factory=dict)  # "outcome: arm vs ref" -> power per N
    effect: dict[str, list[float]] = field(default_factory=dict)  # mean estimated effect per N
    sd: dict[str, float] = field(default_factory=dict)  # SD of participant means in the arm, largest N
    sd_ref: dict[str, float] = field(default_factory=dict)  # ... in the reference arm
    primary: str = ""
    arms: int = 2
    notes: list[str] = field(default_factory=list)

    def interval(self, p: float) -> tuple[float, float]:
        half = 1.96 * math.sqrt(max(p * (1 - p), 1e-12) / self.reps)
        return max(0.0, p - half), min(1.0, p + half)

    def n_for_80(self, key: str) -> str:
        """The smallest simulated N with power >= 0.8, else the normal-approximation N from the effect."""
        for n, p in zip(self.ns, self.power[key]):
            if p >= 0.8:
                return str(n)
        delta = abs(self.effect[key][-1])
        if delta < 1e-9:
            return "none (no effect)"
        return f"about {self.n_needed(delta, self.sd[key], sd_ref=self.sd_ref.get(key))} (extrapolated)"

    def n_needed(self, delta: float, sd: float, arms: int = 0, sd_ref: float | None = None) -> int:
        """Total N for 80 % power of a contrast of participant means with the two arms' own SDs
        (``sd``, ``sd_ref``; equal allocation, normal approximation: n per arm =
        (z + z_0.8)^2 (sd^2 + sd_ref^2) / delta^2)."""
        z = 1.959963984540054 if abs(self.alpha - 0.05) < 1e-12 else _z(1 - self.alpha / 2)
        sd_ref = sd if sd_ref is None else sd_ref
        per_arm = (z + Z80) ** 2 * (sd ** 2 + sd_ref ** 2) / delta ** 2
        return int(math.ceil(per_arm)) * (arms or self.arms)

    def text(self) -> str:
        lines = [f"power of the pre-registered test (protocol {self.name}, sha256 {self.protocol_sha256[:12]}); "
                 f"{self.reps} simulated studies per N; users: {self.users}; session drift {self.drift:g} (logit SD); "
                 f"alpha {self.alpha:g}",
                 f"{'outcome: comparison':<42} " + " ".join(f"N={n:<6}" for n in self.ns) + "  N for 80 %"]
        for key in sorted(self.power, key=lambda k: (not k.startswith(self.primary + ":"), k)):
            lines.append(f"{key:<42} " + " ".join(f"{p:<8.2f}" for p in self.power[key])
                         + f"  {self.n_for_80(key)}")
        lines.append("mean estimated effect at the largest N (arm minus reference), SD of participant means in "
                     "the arm and in the reference arm (each arm its own variance; t test, Satterthwaite df):")
        for key in sorted(self.effect):
            lines.append(f"  {key:<40} {self.effect[key][-1]:+.3f}   sd {self.sd[key]:.3f} / "
                         f"{self.sd_ref.get(key, self.sd[key]):.3f}")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def write(self, out: Path) -> None:
        write_text_atomic(out / "power.txt", self.text() + "\n")
        write_json_atomic(out / "power.json", {"protocol": self.name, "protocol_sha256": self.protocol_sha256,
                                               "ns": self.ns, "reps": self.reps, "alpha": self.alpha,
                                               "users": self.users, "drift": self.drift, "power": self.power,
                                               "effect": self.effect, "sd": self.sd, "sd_ref": self.sd_ref,
                                               "test": "t, arm-specific variances, Satterthwaite df",
                                               "notes": self.notes})


def _z(q: float) -> float:
    return float(distributions.norm_ppf(q))


def welch(mu_a: np.ndarray, var_a: np.ndarray, n_a: np.ndarray, mu_r: np.ndarray, var_r: np.ndarray,
          n_r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(difference, standard error, Satterthwaite df, two-sided t p) of two groups' means from their
    own variances (``var_*``: sample variances with ddof 1, ``n_*``: sizes), vectorised."""
    va, vr = var_a / n_a, var_r / n_r
    diff, se = mu_a - mu_r, np.sqrt(va + vr)
    with np.errstate(divide="ignore", invalid="ignore"):
        df = (va + vr) ** 2 / (va ** 2 / (n_a - 1) + vr ** 2 / (n_r - 1))
        df = np.where(np.isfinite(df), df, np.minimum(n_a, n_r) - 1.0)
        pval = np.where(se > 0, 2 * distributions.t_sf(np.abs(diff) / np.where(se > 0, se, 1), df),
                        np.where(diff != 0, 0.0, 1.0))
    return diff, se, df, pval


def arm_tests(y: np.ndarray, arms: np.ndarray, n_arms: int, ref: int
              ) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Tests of each arm against ``ref`` from participant means ``y`` (reps, n) and arm indices
    (reps, n): {arm: (difference, standard error, two-sided p)} per rep, each arm with its own
    variance and Satterthwaite's df (module docstring)."""
    groups = [(arms == a) for a in range(n_arms)]
    counts = np.stack([g.sum(axis=1) for g in groups], axis=1).astype(float)
    mu = np.stack([(y * g).sum(axis=1) for g in groups], axis=1) / counts
    var = np.stack([((y - mu[:, [a]]) ** 2 * g).sum(axis=1) for a, g in enumerate(groups)], axis=1) / (counts - 1)
    out = {}
    for a in range(n_arms):
        if a == ref:
            continue
        diff, se, _, pval = welch(mu[:, a], var[:, a], counts[:, a], mu[:, ref], var[:, ref], counts[:, ref])
        out[a] = (diff, se, pval)
    return out


def arm_sds(y: np.ndarray, arms: np.ndarray, n_arms: int) -> np.ndarray:
    """(n_arms,) SD of participant means per arm, averaged (as variances) over the reps."""
    out = np.zeros(n_arms)
    for a in range(n_arms):
        g = arms == a
        n = g.sum(axis=1)
        mu = (y * g).sum(axis=1) / n
        out[a] = math.sqrt(float(np.mean(((y - mu[:, None]) ** 2 * g).sum(axis=1) / (n - 1))))
    return out


def user_tables(users: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    return (np.stack([u.truth.p_success for u in users]), np.stack([u.truth.engagement for u in users]))


def power_study(protocol: Protocol, ns: list[int], reps: int, seed: int, users: list[Any], users_name: str,
                drift: float = 0.3, progress: TextIO | None = None) -> PowerReport:
    """Simulate ``reps`` studies for every N in ``ns`` (module docstring)."""
    if not users:
        raise ConfigError("study power: the user set is empty")
    if min(ns) < len(protocol.arms) * 2:
        raise ConfigError(f"--n {min(ns)}: each of the {len(protocol.arms)} arms needs at least 2 participants; "
                          f"give N >= {2 * len(protocol.arms)}")
    p_users, e_users = user_tables(users)
    policies = [SessionPolicies(protocol, arm) for arm in protocol.arms]
    ref = [a.name for a in protocol.arms].index(protocol.analysis.reference_arm)
    report = PowerReport(protocol.name, protocol.sha256, list(ns), reps, protocol.analysis.alpha, users_name, drift,
                         primary=protocol.primary)
    report.arms = len(protocol.arms)
    report.notes = [f"{o}: not simulated (the simulation plays {', '.join(SIMULATED_OUTCOMES)}); analysed by "
                    "study analyse" for o in protocol.outcomes if o not in SIMULATED_OUTCOMES]
    report.notes += [f"arm {arm.name}: {pol.offline.note}" for arm, pol in zip(protocol.arms, policies)
                     if getattr(pol.offline, "note", "")]  # what a policy's offline form leaves out
    rng = np.random.default_rng(seed)
    S = protocol.sessions.per_participant
    for n in ns:
        arms = np.stack([blocked_arms(protocol, n, rng) for _ in range(reps)])  # (reps, n)
        who = rng.integers(len(users), size=(reps, n))
        means = np.zeros((reps, n, 3))
        for a, pol in enumerate(policies):
            sel = np.flatnonzero(arms.ravel() == a)
            idx = who.ravel()[sel]
            for s in range(1, S + 1):
                episode = pol.start(len(sel), s)
                p = _drifted(p_users[idx], drift, rng)
                means.reshape(-1, 3)[sel] += play_sessions(episode, p, e_users[idx], pol.turns, rng) / S
        for o, outcome in enumerate(SIMULATED_OUTCOMES):
            if outcome not in protocol.outcomes:
                continue
            for a, (diff, se, pval) in arm_tests(means[:, :, o], arms, len(policies), ref).items():
                key = f"{outcome}: {protocol.arms[a].name} vs {protocol.arms[ref].name}"
                report.power.setdefault(key, []).append(float(np.mean(pval < report.alpha)))
                report.effect.setdefault(key, []).append(float(diff.mean()))
                sds = arm_sds(means[:, :, o], arms, len(policies))
                report.sd[key] = float(sds[a])
                report.sd_ref[key] = float(sds[ref])
        if progress:
            print(f"study power: N={n}: {reps} studies simulated", file=progress, flush=True)
    return report
