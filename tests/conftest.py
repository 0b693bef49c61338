"""Shared test set-up: LSL in machine scope, qi quiet, the published dataset extracted to a temp folder."""
from __future__ import annotations

import fcntl
import hashlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

import pytest

# One BLAS thread in the test processes and every process they start: make test runs 4 workers on 2 cores,
# where OpenBLAS's own threads only spin for a share of the CPU (measured: `evaluate --personalise --limit 1`
# 16.9 s of CPU with the default threads, 14.3 s with one, the same wall time). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from nao_trainer.eeg.lsl_scope import PORT_RANGE  # imports neither pylsl nor qi: safe before LSLAPICFG is set

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("NAO_TRAINER_SHARED", ROOT.parent / "shared")).resolve()
DATA = SHARED / "data" / "sequence-learning"


def lsl_config(given: str | None) -> str:
    """The liblsl config of the tests: ``given`` (or ../shared/lsl_api.cfg, or the project's), machine scope
    as it says, with the port range widened when it sets none.

    Machine scope finds a stream by asking each port of liblsl's range on 127.0.0.1 (loopback multicast
    carries nothing here). With liblsl's default of 32 ports, two suites side by side hold more outlets
    than that, and a recorder then waits in vain for a stream on a random port (seen once under double
    load). The widened copy is written beside the temporary files, named by its content.
    """
    src = Path(given) if given else SHARED / "lsl_api.cfg"
    if not given and not src.exists():
        src = ROOT / "config" / "lsl_api.cfg"
    text = src.read_text(encoding="utf-8")
    if re.search(r"^\s*PortRange\s*=", text, re.M):
        return str(src)
    line = f"PortRange = {PORT_RANGE}\n"
    text = re.sub(r"^\[ports\]\n", "[ports]\n" + line, text, count=1, flags=re.M) if re.search(
        r"^\[ports\]$", text, re.M) else text.rstrip("\n") + "\n[ports]\n" + line
    path = Path(tempfile.gettempdir()) / f"nao-trainer-tests-lsl-{hashlib.sha256(text.encode()).hexdigest()[:12]}.cfg"
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    return str(path)


# Before anything imports pylsl or qi: keep LSL discovery on this machine and qi's logs silent.
os.environ["LSLAPICFG"] = lsl_config(os.environ.get("LSLAPICFG"))
os.environ.setdefault("QI_LOG_LEVEL", "silent")

# A suite started in the background by a non-interactive shell (`make test &` in a script) inherits SIGINT
# ignored, and so would every process it starts: the tests that press Ctrl-C on a command (train, run, the
# stand-in) would wait for an exit that never comes. A handler here is reset to the default in each child.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _run_root(tmp_path_factory) -> Path:
    """This run's temp root, shared by the xdist workers (each has <run>/popen-gwN of its own)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def _extract(archive: str, tmp_path_factory, name: str) -> Path:
    """``archive`` extracted once per test run, also under ``pytest -n`` (the workers share this run's temp root
    and take turns on a lock: the first extracts, ~5 s for the bands, the others read). Tests only read it."""
    path = DATA / archive
    if not path.exists():
        pytest.fail(f"{path} is missing: the tests need ../shared/data/sequence-learning beside the repo")
    root = _run_root(tmp_path_factory)
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


@pytest.fixture
def own_cache(dataset_root, tmp_path_factory, tmp_path, monkeypatch) -> Path:
    """``XDG_CACHE_HOME`` of this test alone (no Bayes plan or import cache of another test), holding a copy of
    the run's one import of the published sessions: importing the 50 sessions costs ~6 s of CPU, paid once per
    run (under ``pytest -n`` the workers take turns on a lock, as for the extraction)."""
    from nao_trainer.data import dataset
    from nao_trainer.learn.artifacts import load_manifest

    compat = load_manifest(None).get("compat")
    root = _run_root(tmp_path_factory)
    name = dataset.cache_dir(dataset_root, compat).name
    shared = root / "import-cache" / name
    with open(root / "import-cache.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / ".complete").exists():
            dataset.import_dataset(dataset_root, compat=compat, cache_dir=shared)
            (shared / ".complete").write_text("")
    mine = tmp_path / "cache"
    shutil.copytree(shared, mine / "nao-trainer" / "import" / name, ignore=shutil.ignore_patterns(".complete"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(mine))
    return mine


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
