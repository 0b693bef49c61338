"""The pooled psychometric prior on disk: plain JSON, loadable without the dataset.

``sim/psychometric/pooled.json`` ships the ``core.psychometric.PooledModel`` fitted on the 50 published
sessions; sessions use it to report their span (``core.psychometric.session_span``) in the summary and the
study table. It is written by ``nao-trainer fit SOURCE --out DIR --psychometric FILE`` (the turns' levels and
outcomes only, so the result does not depend on ``--compat``) and records the dataset fingerprint, like the
user models of ``sim/models``. Deliberately no library versions: a refit on another machine writes the same
bytes, which the tests check against the shipped file.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import psychometric
from nao_trainer.errors import DataError, UserError
from nao_trainer.files import PROJECT_ROOT, JsonFormat, cannot_write, read_json, write_json_atomic

PRIOR_FILE = JsonFormat("nao-trainer/psychometric-prior", 1, "psychometric prior", "psychometric prior",
                        "refit with `nao-trainer fit SOURCE --out DIR --psychometric FILE`")
#: Where the project's prior ships (fitted from the published data).
DEFAULT_PRIOR = PROJECT_ROOT / "sim" / "psychometric" / "pooled.json"
_PARAMS = ("mu", "tau", "sigma", "lapse")


def fit_prior(sessions: np.ndarray, levels: np.ndarray, successes: np.ndarray) -> tuple[psychometric.PooledModel, int]:
    """The pooled model fitted on every session's per-level counts, and the number of sessions."""
    counts = psychometric.session_counts(sessions, levels, successes)
    return psychometric.fit(counts), len(counts)


def save_prior(path: Path, model: psychometric.PooledModel, info: dict[str, Any]) -> Path:
    """Write the prior (atomic); ``info`` adds provenance (dataset fingerprint, sessions, turns, compat)."""
    doc = {
        **PRIOR_FILE.header(),
        **info,
        "model": "P(success | length x) = (1 - lapse) * Phi((theta - x) / sigma), theta ~ Normal(mu, tau^2) "
                 "across participants (core.psychometric)",
        "lengths": [float(x) for x in psychometric.LENGTHS],
        **{k: round(float(getattr(model, k)), 9) for k in _PARAMS},
    }
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, doc)
    except OSError as exc:
        raise UserError(cannot_write(path, "the psychometric prior", exc, "choose another --psychometric")) from None
    return path


def load_prior(path: Path | None = None) -> psychometric.PooledModel:
    """The prior of ``path`` (default: the shipped one), checked; DataError naming the file otherwise."""
    path = Path(path) if path else DEFAULT_PRIOR
    doc = PRIOR_FILE.check(read_json(path, DataError, fix=PRIOR_FILE.fix), path, DataError)
    values = {k: doc.get(k) for k in _PARAMS}
    for k, v in values.items():  # finite and in range (core.psychometric.RANGES): NaN, 1e300 or 400 digits are not
        problem = psychometric.parameter_problem(k, v)
        if problem is not None:
            raise DataError(f"{path}: key {k!r} {problem}; {PRIOR_FILE.fix}")
    return psychometric.PooledModel(**{k: float(v) for k, v in values.items()})
