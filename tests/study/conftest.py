"""Study tests keep their study keys in a temporary key store (never the user's ~/.local/share)."""
from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _study_keys(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("NAO_TRAINER_KEYS", str(tmp_path_factory.mktemp("keys")))
