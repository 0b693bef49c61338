"""Study tests keep their study keys in a temporary key store (never the user's ~/.local/share)."""
from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _study_keys(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("NAO_TRAINER_KEYS", str(tmp_path_factory.mktemp("keys")))


@pytest.fixture(scope="session")
def pg_cluster():
    """ONE throwaway PostgreSQL server for the test session (see tests/_pg_cluster.py), in a folder of
    its own under the system's temporary folder (pytest's is private to root; the server runs as nobody)."""
    import shutil
    import tempfile

    from tests._pg_cluster import Cluster, find_bin

    if find_bin() is None:
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not found: install the OS package postgresql")
    pytest.importorskip("psycopg", reason="psycopg not installed: pip install 'nao-trainer[study-pg]'")
    cluster = Cluster(Path(tempfile.mkdtemp(prefix="nao-trainer-pg-")))
    try:
        cluster.start()
        yield cluster
    finally:
        cluster.stop()
        shutil.rmtree(cluster.base, ignore_errors=True)
