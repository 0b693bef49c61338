"""Auditory n-back rules: the stream, judging by signal detection, d′, the block's success criterion.

Pure: no I/O; randomness comes in as a ``numpy.random.Generator``.

Sources of the parameters (named again in docs/explanation/tasks.md):

* Block and timing: Jaeggi, Buschkuehl, Jonides & Perrig (2008), "Improving fluid intelligence with training on
  working memory", PNAS 105(19), 6829-6833: a block is 20 + n stimuli, 6 of them targets; a stimulus every 3 s
  (500 ms stimulus, 2500 ms interstimulus interval); the level goes up after a block with fewer than 3 errors and
  down after more than 5 (the adaptive rule). Here one block is one turn; its success (the MDP's outcome) is
  Jaeggi's "up" criterion: fewer than ``MAX_ERRORS_FOR_SUCCESS + 1`` errors (misses + false alarms).
* Loads n = 1..4: 4-back is within the range used for assessment and training (Jaeggi et al. 2008 trained beyond
  n = 4; the CogSci 2012 analysis of a 4-back assessment, mindmodeling.org/cogsci2012/papers/0290), so the MDP's
  four levels are n = 1, 2, 3, 4.
* d′ = z(H) − z(F) with the log-linear correction for rates of 0 and 1 (Hautus 1995, "Corrections for extreme
  proportions and their biasing effects on estimated values of d′", Behavior Research Methods, Instruments, &
  Computers 27, 46-51; also Stanislaw & Todorov 1999, Behavior Research Methods 31, 137-149): add 0.5 to the hit
  and false-alarm counts and 1 to the numbers of targets and non-targets.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import comb
from statistics import NormalDist

import numpy as np

#: Consonants spoken one at a time (Jaeggi et al. 2008 used 8 consonants in the auditory stream).
LETTERS: tuple[str, ...] = ("C", "G", "H", "K", "P", "Q", "T", "W")
#: The button that says "match" (the front head button's letter, ``ports.BUTTON_LETTERS``).
MATCH_BUTTON = "A"
FILLERS = 20  # a block is FILLERS + n stimuli (Jaeggi et al. 2008)
TARGETS = 6  # targets per block (Jaeggi et al. 2008)
SOA_S = 3.0  # one stimulus every 3 s: 0.5 s stimulus + 2.5 s interval (Jaeggi et al. 2008)
MAX_ERRORS_FOR_SUCCESS = 2  # fewer than 3 errors moves the level up (Jaeggi et al. 2008): the block succeeded
_Z = NormalDist()


def block_length(n: int, fillers: int = FILLERS) -> int:
    """Stimuli in a block of load ``n``."""
    return fillers + n


def make_stream(rng: np.random.Generator, n: int, targets: int = TARGETS,
                fillers: int = FILLERS) -> tuple[tuple[str, ...], tuple[bool, ...]]:
    """A stream of ``fillers + n`` letters with exactly ``targets`` n-back matches (and no accidental ones).

    Target positions are drawn among n..end; every other letter differs from the one n back."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n!r}")
    length = block_length(n, fillers)
    if not 0 <= targets <= length - n:
        raise ValueError(f"targets must be in 0..{length - n}, got {targets!r}")
    at = set(int(i) for i in rng.choice(np.arange(n, length), size=targets, replace=False))
    letters: list[str] = []
    for i in range(length):
        if i in at:
            letters.append(letters[i - n])
            continue
        choices = [c for c in LETTERS if i < n or c != letters[i - n]]
        letters.append(choices[int(rng.integers(len(choices)))])
    return tuple(letters), tuple(i in at for i in range(length))


@dataclass(frozen=True)
class Outcome:
    """A block judged by signal detection."""

    hits: int
    misses: int
    false_alarms: int
    correct_rejections: int

    @property
    def errors(self) -> int:
        return self.misses + self.false_alarms

    @property
    def success(self) -> bool:
        """Jaeggi et al. (2008)'s "level up" criterion: fewer than 3 errors in the block."""
        return self.errors <= MAX_ERRORS_FOR_SUCCESS

    @property
    def d_prime(self) -> float:
        return d_prime(self.hits, self.misses, self.false_alarms, self.correct_rejections)


def d_prime(hits: int, misses: int, false_alarms: int, correct_rejections: int) -> float:
    """z(H) − z(F) with the log-linear correction (Hautus 1995): finite for rates of 0 and 1."""
    h = (hits + 0.5) / (hits + misses + 1)
    f = (false_alarms + 0.5) / (false_alarms + correct_rejections + 1)
    return _Z.inv_cdf(h) - _Z.inv_cdf(f)


def responded(onsets: tuple[float, ...], window_s: float, press_times: tuple[float, ...]) -> tuple[bool, ...]:
    """Which stimuli got a press: a press belongs to the last stimulus whose onset precedes it (within
    ``window_s`` of it); several presses to one stimulus count once; a press before the first onset counts for none."""
    out = [False] * len(onsets)
    for t in press_times:
        i = int(np.searchsorted(np.asarray(onsets), t, side="right")) - 1
        if 0 <= i < len(onsets) and t - onsets[i] <= window_s:
            out[i] = True
    return tuple(out)


def judge(targets: tuple[bool, ...], responses: tuple[bool, ...], n: int) -> Outcome:
    """Hits, misses, false alarms and correct rejections; the first ``n`` stimuli cannot be targets and a press
    to one of them is a false alarm."""
    hits = sum(t and r for t, r in zip(targets, responses))
    misses = sum(t and not r for t, r in zip(targets, responses))
    fas = sum((not t) and r for t, r in zip(targets, responses))
    crs = sum((not t) and not r for t, r in zip(targets, responses))
    return Outcome(hits, misses, fas, crs)


def rates(d: float, c: float) -> tuple[float, float]:
    """Equal-variance signal detection: P(hit) = Φ(d′/2 − c), P(false alarm) = Φ(−d′/2 − c)."""
    return _Z.cdf(d / 2 - c), _Z.cdf(-d / 2 - c)


def success_probability(d: float, c: float, n: int, targets: int = TARGETS, fillers: int = FILLERS) -> float:
    """P(a block of load ``n`` succeeds) for an observer (d′, c): P(misses + false alarms <= 2), exactly."""
    h, f = rates(d, c)
    nontargets = block_length(n, fillers) - targets
    miss = _binomial(targets, 1 - h)
    fa = _binomial(nontargets, f)
    return float(sum(miss[i] * fa[j] for i in range(len(miss)) for j in range(len(fa))
                     if i + j <= MAX_ERRORS_FOR_SUCCESS))


def _binomial(n: int, p: float) -> list[float]:
    return [comb(n, k) * p ** k * (1 - p) ** (n - k) for k in range(n + 1)]
