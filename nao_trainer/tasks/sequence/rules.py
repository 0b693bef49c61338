"""The sequence learning task's rules (paper section 3.1): letters, sequences, judging, the participant's mistakes.

Pure: no I/O, no global randomness. Randomness comes in as a ``numpy.random.Generator``. Difficulty level ``D``
in 1..4 is a sequence of ``L`` = 3/5/7/9 letters (``core.task.LENGTHS``, the MDP's own coordinate) over A, B, C;
the participant repeats it on three head buttons. Moved here from ``core/task.py`` and
``answers/simulated.py`` (issue 26) without a change of behaviour.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from nao_trainer.core.task import level_of

LETTERS: tuple[str, ...] = ("A", "B", "C")
#: Relative frequency of mistake kinds when a simulated participant fails a turn.
MISTAKES: dict[str, float] = {"substitute": 0.6, "swap": 0.25, "omit": 0.15}


def generate_sequence(rng: np.random.Generator, length: int) -> tuple[str, ...]:
    """A uniformly random sequence of ``length`` letters drawn from A/B/C with ``rng``."""
    level_of(length)  # validates
    return tuple(LETTERS[i] for i in rng.integers(0, len(LETTERS), size=length))


def is_correct(sequence: Sequence[str], response: Sequence[str]) -> bool:
    """True when the response repeats the sequence exactly (same letters, same order, same count)."""
    return tuple(s.upper() for s in sequence) == tuple(r.upper() for r in response)


def make_mistake(sequence: tuple[str, ...], rng: np.random.Generator) -> tuple[tuple[str, ...], str]:
    """A response that differs from ``sequence`` the way people err; returns (response, kind)."""
    kinds = list(MISTAKES)
    kind = kinds[int(rng.choice(len(kinds), p=np.array(list(MISTAKES.values()))))]
    seq = list(sequence)
    if kind == "swap":
        pairs = [i for i in range(len(seq) - 1) if seq[i] != seq[i + 1]]
        if pairs:
            i = pairs[int(rng.integers(len(pairs)))]
            seq[i], seq[i + 1] = seq[i + 1], seq[i]
            return tuple(seq), kind
        kind = "substitute"
    if kind == "omit":
        del seq[int(rng.integers(len(seq)))]
        return tuple(seq), kind
    i = int(rng.integers(len(seq)))
    others = [c for c in LETTERS if c != seq[i]]
    seq[i] = others[int(rng.integers(len(others)))]
    return tuple(seq), "substitute"
