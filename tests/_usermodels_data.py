"""Shared helpers of the user-model tests: one import of the published data per test process.

The per-session import cache lives under pytest's base temp folder, so the test files that need
the turn table pay for the import once (about 3 s) and then read the cache (well under 1 s).
"""
from __future__ import annotations

from pathlib import Path

from nao_trainer.data.dataset import ImportResult, import_dataset


def shared_cache(tmp_path_factory, compat: str | None) -> Path:
    return tmp_path_factory.getbasetemp() / f"usermodels-import-cache-{compat or 'default'}"


def import_published(dataset_root: Path, tmp_path_factory, compat: str | None = "authors2018") -> ImportResult:
    return import_dataset(dataset_root, compat=compat, cache_dir=shared_cache(tmp_path_factory, compat))
