"""Fitted user simulators on disk: plain JSON (no pickles), loadable without the dataset.

A model folder (default: ``<repo>/sim/models/``) holds

* ``manifest.json``: format version, dataset fingerprint, feature encoding, library versions,
  compatibility mode, K, fit options and the cluster table (sizes, means, RMSEs, files);
* ``cluster_<id>.json``: ``UserSimulator.to_dict()`` of each cluster (tables over all 108 turn
  states, with their own fingerprint).

``load_simulator("2")`` reads cluster 2 of the default folder; ``load_simulator("path.json")``
reads one file. Files are written to a temporary name and renamed, so a reader never sees half
a file.
"""
from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from nao_trainer.core.simulation import FORMAT_VERSION as SIMULATOR_FORMAT_VERSION
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.errors import DataError, UserError
from nao_trainer.files import PROJECT_ROOT, JsonFormat, cannot_write, read_json, write_json_atomic

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "nao-trainer/user-models"
MANIFEST_VERSION = 1
MANIFEST_FILE = JsonFormat(MANIFEST_FORMAT, MANIFEST_VERSION, "user-model manifest", "manifest",
                           "refit with `nao-trainer fit`")
#: Where the project's default user models ship (fitted from the published data).
DEFAULT_MODELS_DIR = PROJECT_ROOT / "sim" / "models"
MODELS_ENV = "NAO_TRAINER_MODELS"


def default_models_dir() -> Path:
    """``$NAO_TRAINER_MODELS`` when set, else ``<repo>/sim/models``."""
    env = os.environ.get(MODELS_ENV)
    return Path(env) if env else DEFAULT_MODELS_DIR


def library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("nao-trainer", "numpy", "scikit-learn", "scipy"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            pass
    return out


def cluster_file(cluster_id: int) -> str:
    return f"cluster_{cluster_id}.json"


def save_models(out_dir: Path, simulators: list[UserSimulator], clusters: list[dict[str, Any]],
                info: dict[str, Any]) -> Path:
    """Write ``cluster_<id>.json`` per simulator and the manifest; returns the manifest path.

    ``clusters[i]`` is the summary row of ``simulators[i]`` (must hold ``id``); ``info`` adds
    top-level manifest fields (dataset fingerprint, compat, k, options, ...).
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        rows = []
        for sim, row in zip(simulators, clusters, strict=True):
            name = cluster_file(int(row["id"]))
            write_json_atomic(out / name, sim.to_dict())
            rows.append({**row, "file": name, "fingerprint": sim.fingerprint()})
    except OSError as exc:
        raise UserError(cannot_write(out, "the user models", exc, "choose another --out")) from None
    manifest = {
        **MANIFEST_FILE.header(),
        "simulator_format_version": SIMULATOR_FORMAT_VERSION,
        **info,
        "library_versions": library_versions(),
        "clusters": rows,
    }
    path = out / MANIFEST
    try:
        write_json_atomic(path, manifest)
    except OSError as exc:
        raise UserError(cannot_write(path, "", exc, "choose another --out")) from None
    return path


def _read_json(path: Path) -> Any:
    return read_json(path, DataError, fix="refit with `nao-trainer fit`")


def load_manifest(models_dir: Path | None = None) -> dict[str, Any]:
    """The manifest of a model folder, checked for format and version."""
    folder = Path(models_dir) if models_dir else default_models_dir()
    path = folder / MANIFEST
    if not path.exists():
        raise DataError(f"{path}: no user models here; create them with `nao-trainer fit DATASET_ROOT --out {folder}`")
    return MANIFEST_FILE.check(_read_json(path), path, DataError)


def available_models(models_dir: Path | None = None) -> list[str]:
    """Cluster ids listed in a folder's manifest (as strings, e.g. ``["1", "2", "3"]``)."""
    return [str(row["id"]) for row in load_manifest(models_dir).get("clusters", [])]


def load_simulator_file(path: Path) -> UserSimulator:
    """One simulator JSON file; DataError naming the file on any problem."""
    data = _read_json(Path(path))
    if not isinstance(data, dict):
        raise DataError(f"{path}: not a user simulator (expected a JSON object)")
    try:
        return UserSimulator.from_dict(data, source=str(path))
    except ValueError as exc:  # DefinitionMismatch included; core names the values, the fix is named here
        raise DataError(f"{exc}; refit it with `nao-trainer fit`") from None


def load_simulator(spec: str, models_dir: Path | None = None) -> UserSimulator:
    """A simulator by cluster id (``"1"``, ``"cluster-1"``, ``"cluster_1"``) or by path to a JSON file.

    Ids are looked up in ``models_dir`` (default: ``default_models_dir()``). An unknown id raises
    DataError listing the available ones.
    """
    text = str(spec).strip()
    as_path = Path(text).expanduser()
    if text.endswith(".json") or os.sep in text or as_path.is_file():
        return load_simulator_file(as_path)
    folder = Path(models_dir) if models_dir else default_models_dir()
    cid = text.lower().removeprefix("cluster").lstrip("-_ ")
    manifest = load_manifest(folder)
    for row in manifest.get("clusters", []):
        if str(row.get("id")) == cid:
            sim = load_simulator_file(folder / row.get("file", cluster_file(int(row["id"]))))
            if row.get("fingerprint") and row["fingerprint"] != sim.fingerprint():
                raise DataError(f"{folder / row['file']}: does not match the manifest's fingerprint; "
                                "refit with `nao-trainer fit`")
            return sim
    ids = ", ".join(str(r.get("id")) for r in manifest.get("clusters", [])) or "none"
    raise DataError(f"unknown user model {spec!r}: {folder} has clusters {ids} (or give a path to a simulator .json)")
