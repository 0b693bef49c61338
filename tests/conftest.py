"""Shared test set-up: LSL in machine scope, qi quiet, the published dataset extracted to a temp folder."""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("NAO_TRAINER_SHARED", ROOT.parent / "shared")).resolve()
DATA = SHARED / "data" / "sequence-learning"

# Before anything imports pylsl or qi: keep LSL discovery on this machine and qi's logs silent.
if not os.environ.get("LSLAPICFG"):
    cfg = SHARED / "lsl_api.cfg"
    os.environ["LSLAPICFG"] = str(cfg if cfg.exists() else ROOT / "config" / "lsl_api.cfg")
os.environ.setdefault("QI_LOG_LEVEL", "silent")


def _extract(archive: str, tmp_path_factory, name: str) -> Path:
    """``archive`` extracted once per test run, also under ``pytest -n`` (the workers share this run's temp root
    and take turns on a lock: the first extracts, ~5 s for the bands, the others read). Tests only read it."""
    path = DATA / archive
    if not path.exists():
        pytest.fail(f"{path} is missing: the tests need ../shared/data/sequence-learning beside the repo")
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # xdist: <run>/popen-gwN per worker
    dest = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (dest / ".extracted").exists():
            shutil.rmtree(dest, ignore_errors=True)  # a worker that died mid-extraction
            dest.mkdir(parents=True)
            subprocess.run(["tar", "-xJf", str(path), "-C", str(dest)], check=True)
            (dest / ".extracted").write_text(archive)
    return dest / "clean_data"


@pytest.fixture(scope="session")
def dataset_root(tmp_path_factory) -> Path:
    """The 50 published sessions (band files) as ``<root>/user_<id>/session_<k>/``."""
    return _extract("clean_data_bands.tar.xz", tmp_path_factory, "bands")


@pytest.fixture(scope="session")
def raw_root(tmp_path_factory) -> Path:
    """The 4 published sessions with raw Muse recordings (``robot_N``, ``user_N``, ``intro``)."""
    return _extract("raw_sessions.tar.xz", tmp_path_factory, "raw")


@pytest.fixture(scope="session")
def derived_dir() -> Path:
    """The authors' derived tables (read-only, space-separated)."""
    return DATA / "derived"


def pytest_collection_modifyitems(config, items) -> None:
    """Files with a test marked ``slow`` first, the rest after, each file's own order kept.

    ``make test`` hands whole files to the workers (``--dist loadfile``) in collection order
    (pytest.ini turns off xdist's reordering by test count, which put the long few-test files last):
    the long files start early and the short ones fill in, so the workers end together instead of one
    playing a long session alone at the end.
    """
    slow = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow)  # a stable sort: only the files move
