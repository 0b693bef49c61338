"""The sequence learning task (paper section 3.1): levels, sequences and scoring.

Pure: no I/O, no global randomness. Randomness comes in as a ``numpy.random.Generator``.

Difficulty level ``D`` in 1..4 is proportional to sequence length ``L`` in 3/5/7/9 over the
letters A, B, C. The participant repeats the spoken sequence on three buttons.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LETTERS: tuple[str, ...] = ("A", "B", "C")
LEVELS: tuple[int, ...] = (1, 2, 3, 4)
LENGTHS: tuple[int, ...] = (3, 5, 7, 9)


def length_of(level: int) -> int:
    """Sequence length of a difficulty level (1 -> 3, ..., 4 -> 9)."""
    if level not in LEVELS:
        raise ValueError(f"level must be one of {LEVELS}, got {level!r}")
    return LENGTHS[level - 1]


def level_of(length: int) -> int:
    """Difficulty level of a sequence length (3 -> 1, ..., 9 -> 4)."""
    if length not in LENGTHS:
        raise ValueError(f"sequence length must be one of {LENGTHS}, got {length!r}")
    return LENGTHS.index(length) + 1


def generate_sequence(rng: np.random.Generator, length: int) -> tuple[str, ...]:
    """A uniformly random sequence of ``length`` letters drawn from A/B/C with ``rng``."""
    level_of(length)  # validates
    return tuple(LETTERS[i] for i in rng.integers(0, len(LETTERS), size=length))


def is_correct(sequence: Sequence[str], response: Sequence[str]) -> bool:
    """True when the response repeats the sequence exactly (same letters, same order, same count)."""
    return tuple(s.upper() for s in sequence) == tuple(r.upper() for r in response)


def score(level: int, success: bool) -> int:
    """The paper's equation (1): +level on success, -1 on failure.

    A constant penalty keeps harder levels attractive to a score-maximising agent.
    """
    length_of(level)
    return level if success else -1


def signed_score(level: int, success: bool) -> int:
    """The published data's score: +level on success, -level on failure.

    This is also the *previous result* feature of the MDP state (range -4..4).
    """
    length_of(level)
    return level if success else -level
