"""The MDP's difficulty levels and the paper's scores (equation (1)), shared by every task.

Pure. A task (``nao_trainer.tasks``) says what a level means; the MDP (``core.mdp``) has four levels whose
coordinate in its state label is the sequence length ``L`` in 3/5/7/9 of the published data (level ``D`` = 1..4),
kept so that stored policies, simulators and the published data's states keep their meaning. The sequence
task's letters, sequences and judging live in ``tasks/sequence`` (issue 26).
"""
from __future__ import annotations

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
