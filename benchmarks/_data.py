"""Where the benchmarks find the published data, and unpacking it (shared by the bench_* scripts).

``shared_dir()``: ``$NAO_TRAINER_SHARED``, else the ``shared`` folder beside the repository.
``extract(archive, dest)``: unpack a ``.tar.xz`` into ``dest`` (not timed by the callers).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def shared_dir() -> Path:
    """The shared data folder: ``$NAO_TRAINER_SHARED`` or ``<repository>/../shared``."""
    return Path(os.environ.get("NAO_TRAINER_SHARED", ROOT.parent / "shared"))


def extract(archive: Path, dest: Path) -> Path:
    """Unpack ``archive`` into ``dest`` (created if needed) and return ``dest``.

    A missing archive or a failing ``tar`` ends the benchmark with one line naming the archive.
    """
    archive, dest = Path(archive), Path(dest)
    if not archive.is_file():
        sys.exit(f"{archive}: not found; set NAO_TRAINER_SHARED to the folder holding data/sequence-learning "
                 "or pass the dataset root")
    dest.mkdir(parents=True, exist_ok=True)
    print(f"extracting {archive} ...", file=sys.stderr, flush=True)
    done = subprocess.run(["tar", "-xJf", str(archive), "-C", str(dest)], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{archive}: cannot extract ({done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'tar failed'})")
    return dest
