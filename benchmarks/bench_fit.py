"""Benchmark: import + fit of the published sessions (target <= 20 s) and a cached re-import (<= 2 s).

Usage: python benchmarks/bench_fit.py [DATASET_ROOT]
Without an argument the published bands archive (../shared/data/sequence-learning) is extracted to a
temporary folder first (not timed). Prints one line per figure; exit 1 if a target is missed.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

from _data import extract, shared_dir

os.environ.setdefault("QI_LOG_LEVEL", "silent")
ARCHIVE = shared_dir() / "data" / "sequence-learning" / "clean_data_bands.tar.xz"
TARGET_FIT_S, TARGET_CACHED_S = 20.0, 2.0


def main(argv: list[str]) -> int:
    from nao_trainer.data.dataset import import_dataset
    from nao_trainer.learn.fitting import FitOptions, Turns, fit_dataset

    with tempfile.TemporaryDirectory() as tmp:
        if argv:
            root = Path(argv[0])
        else:
            root = extract(ARCHIVE, Path(tmp)) / "clean_data"
        cache = Path(tmp) / "cache"
        t0 = time.perf_counter()
        imported = import_dataset(root, compat="authors2018", cache_dir=cache)
        t1 = time.perf_counter()
        result = fit_dataset(Turns.from_columns(imported.table.columns), FitOptions())
        t2 = time.perf_counter()
        again = import_dataset(root, compat="authors2018", cache_dir=cache)
        t3 = time.perf_counter()
    n = len(imported.table.sessions)
    assert again.cached == n and again.table.fingerprint() == imported.table.fingerprint()
    fit_s, cached_s = t2 - t0, t3 - t2
    print(f"sessions: {n}, turns: {len(imported.table)}, clusters: {result.clustering.sizes.tolist()}")
    print(f"import (fresh): {t1 - t0:.2f} s")
    what = f"user models, K-means x{result.options.n_init}, {result.clustering.k} simulators + CV"
    print(f"fit ({what}): {t2 - t1:.2f} s")
    print(f"import + fit: {fit_s:.2f} s (target <= {TARGET_FIT_S:.0f} s) {'OK' if fit_s <= TARGET_FIT_S else 'MISSED'}")
    print(f"cached re-import: {cached_s:.2f} s (target <= {TARGET_CACHED_S:.0f} s) "
          f"{'OK' if cached_s <= TARGET_CACHED_S else 'MISSED'}")
    return 0 if fit_s <= TARGET_FIT_S and cached_s <= TARGET_CACHED_S else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
