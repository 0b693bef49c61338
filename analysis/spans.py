"""Each published session's span at 75 % under the shipped psychometric prior (docs/how-to/session.md, "Span").

    PYTHONPATH=. python analysis/spans.py DATASET_ROOT   # the 50 sessions of the published layout

Prints the prior's span, one line per session (median [90 % interval], letters) and the spread.
"""
from __future__ import annotations

import sys

import numpy as np

from nao_trainer.core import psychometric as ps
from nao_trainer.data.dataset import import_dataset
from nao_trainer.learn.fitting import Turns
from nao_trainer.learn.psychometric_prior import load_prior


def main(root: str) -> None:
    turns = Turns.from_columns(import_dataset(root, compat="authors2018").table.columns)
    names = sorted(np.unique(turns.session).tolist())
    counts = ps.session_counts(turns.session, turns.level, turns.success)
    prior = load_prior()
    p = ps.session_span(prior, np.zeros(8))
    print(f"prior {prior}: span at 75 % {p.median:.2f} [{p.lo:.2f}, {p.hi:.2f}] (width {p.hi - p.lo:.2f})")
    spans = [ps.session_span(prior, c) for c in counts]
    for name, c, s in zip(names, counts, spans):
        print(f"{name:<24} {int(c.sum()):3d} turns  {s.median:5.2f} [{s.lo:5.2f}, {s.hi:5.2f}]")
    med, width = np.array([s.median for s in spans]), np.array([s.hi - s.lo for s in spans])
    print(f"{len(spans)} sessions: median span {np.median(med):.2f} (range {med.min():.2f} to {med.max():.2f}, "
          f"SD {med.std(ddof=1):.2f}); 90 % interval width median {np.median(width):.2f} "
          f"(range {width.min():.2f} to {width.max():.2f})")


if __name__ == "__main__":
    main(sys.argv[1])
