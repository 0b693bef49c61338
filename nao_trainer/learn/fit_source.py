"""From a source to saved user models: import the dataset (or read a turn table), fit, write the artifacts.

``fit_and_save`` is the library side of ``nao-trainer fit``; it returns the report and the fit, and
the command draws the figures from them (``plots.usermodels.draw_fit``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.data import dataset, turn_table
from nao_trainer.data.dataset import COMPAT_MODES, discover, session_name
from nao_trainer.data.engagement import session_engagement
from nao_trainer.data.own import own_session_engagement
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import read_json
from nao_trainer.learn import artifacts, psychometric_prior
from nao_trainer.learn.fitting import FEATURE_ENCODING, FitOptions, FitResult, Turns, fit_dataset


def table_provenance(csv_path: Path, compat: str | None) -> tuple[str | None, list[str]]:
    """(compat mode, skipped sessions) of a turn-table CSV from its sidecar ``<csv>.json`` (``write_table``).

    Without a sidecar: ``compat`` as given and no skipped list. A ``compat`` that contradicts the
    sidecar is a ConfigError: the table's engagement column was computed in the sidecar's mode.
    """
    sidecar = Path(csv_path).with_name(Path(csv_path).name + ".json")
    if not sidecar.exists():
        return compat, []
    fix = "re-create it with `nao-trainer import`"
    prov = read_json(sidecar, DataError, fix=fix)
    if not isinstance(prov, dict) or prov.get("compat") not in COMPAT_MODES:
        raise DataError(f"{sidecar}: key 'compat' must be one of {', '.join(map(str, COMPAT_MODES[1:]))} or null; {fix}")
    skipped = prov.get("skipped", [])
    if not (isinstance(skipped, list) and all(isinstance(v, str) for v in skipped)):
        raise DataError(f"{sidecar}: key 'skipped' must be a list of strings; {fix}")
    recorded = prov["compat"]
    if compat is not None and compat != recorded:
        raise ConfigError(f"{sidecar}: the table was imported with compat {recorded or 'none'}, not {compat}; "
                          f"drop --compat or re-import with `nao-trainer import --compat {compat}`")
    return recorded, list(skipped)


@dataclass
class FittedSource:
    """What :func:`fit_and_save` did: the JSON report and what the figures need."""

    report: dict[str, Any]
    result: FitResult
    turns: Turns
    source: Path
    compat: str | None
    seed: int


def fit_and_save(source: Path, out_dir: Path, compat: str | None = None, k: int = 3, seed: int = 0,
                 cache: Path | str | None = "default",
                 progress: Callable[[str], None] | None = None, select: Any = None,
                 include_simulated: bool = False, psychometric: Path | None = None) -> FittedSource:
    """Import (or read a turn-table CSV), fit and write the artifacts; returns the report and the fit.

    The figures are the command's business (``plots.usermodels.draw_fit``).

    ``cache``: a folder, ``"default"`` (:func:`nao_trainer.data.dataset.cache_dir`) or None (no cache). For a turn-table
    CSV, the compat mode and skipped sessions come from its sidecar (:func:`table_provenance`).
    ``select`` (``data.turn_table.SessionFilter``) keeps some studies / inputs. Sessions of a simulated
    participant are refused (ConfigError) unless ``include_simulated``: user models learnt from made-up
    people must never pass for a study's. ``psychometric``: also fit the pooled psychometric prior
    (``learn.psychometric_prior``) on the same turns and write it to that file.
    """
    say = progress or (lambda _m: None)
    source, out = Path(source), Path(out_dir)
    skipped: list[str] = []
    if source.is_file():
        table = turn_table.read_table(source)
        compat, skipped = table_provenance(source, compat)
        if select is not None:
            table, dropped = select.apply(table)
            for line in dropped:
                say(f"nao-trainer fit: {line}")
            if not len(table):
                raise ConfigError(f"{source}: the filter ({select}) left no session; check --study / --input")
        say(f"{source}: {len(table)} turns from {len(table.sessions)} sessions")
    else:
        cache_dir = dataset.cache_dir(source, compat) if cache == "default" else cache
        imported = dataset.import_dataset(source, compat=compat, cache_dir=cache_dir, progress=say, select=select)
        for line in [str(p) for p in imported.problems] + imported.notes:
            say(f"nao-trainer fit: {line}")
        if imported.excluded:
            say(f"nao-trainer fit: {imported.excluded_summary()}")
        skipped = [str(p) for p in imported.problems]
        table = imported.table
        say(f"imported {len(table)} turns from {len(table.sessions)} sessions ({imported.cached} from cache)")
    say(f"nao-trainer fit: {table.mix()}")
    simulated = turn_table.simulated_sessions(table)
    if simulated and not include_simulated:
        raise ConfigError(f"{source}: {len(simulated)} of {len(table.sessions)} sessions had a simulated participant "
                          f"(input simulated, e.g. {simulated[0]}); user models are learnt from people: add "
                          "--exclude-simulated to leave them out, or --include-simulated to learn from them (pilots, tests)")
    if simulated:
        say(f"nao-trainer fit: learning from {len(simulated)} sessions of simulated participants (--include-simulated)")
    turns = Turns.from_columns(table.columns)
    info = {
        "dataset_fingerprint": table.fingerprint(),
        "dataset_fingerprint_of": "sha256 of the imported turn table's CSV text",
        "compat": compat,
        "k": k,
        "seed": seed,
        "feature_encoding": FEATURE_ENCODING,
        "state_encoding": "index = (level-1)*27 + RF*9 + PR+4 (core.mdp)",
        "mdp_definition": mdp.DEFINITION,
        "cluster_ids": "1..K by increasing mean success rate P1..P4 (ties: mean engagement)",
        "inputs": sorted(set(table["input"].tolist())),
        "studies": sorted(set(table["study"].tolist())),
        "simulated_sessions": len(simulated),
    }
    options = FitOptions(k=k, seed=seed)
    meta = {"compat": compat, "dataset_fingerprint": info["dataset_fingerprint"]}
    result = fit_dataset(turns, options, metadata=meta, progress=say)
    report = {
        "sessions": len(result.user_models.sessions),
        "turns": len(turns.state),
        "skipped": skipped,
        **{key: info[key] for key in ("inputs", "studies", "simulated_sessions")},
        "k": result.clustering.k,
        "inertia": round(result.clustering.inertia, 9),
        **{key: info[key] for key in ("compat", "seed", "dataset_fingerprint")},
        "clusters": [c.summary() for c in result.clusters],
    }
    options_dict = {f: getattr(options, f) for f in options.__dataclass_fields__}
    artifacts.save_models(out, [c.simulator for c in result.clusters], report["clusters"],
                          {**info, "options": options_dict, "sessions": report["sessions"], "turns": report["turns"],
                           "skipped": skipped, "inertia": report["inertia"]})
    say(f"wrote {out / artifacts.MANIFEST} and {len(result.clusters)} simulators")
    if psychometric is not None:
        model, n = psychometric_prior.fit_prior(turns.session, turns.level, turns.success)
        info_prior = {key: info[key] for key in ("dataset_fingerprint", "dataset_fingerprint_of", "compat")}
        path = psychometric_prior.save_prior(Path(psychometric), model,
                                             {**info_prior, "sessions": n, "turns": len(turns.state)})
        model = psychometric_prior.load_prior(path)  # as saved (rounded), so the report and the file agree
        report["psychometric"] = {"file": str(path), **model.__dict__}
        say(f"wrote {path} (pooled psychometric prior: mu {model.mu:g}, tau {model.tau:g}, sigma {model.sigma:.3f}, "
            f"lapse {model.lapse:g})")
    return FittedSource(report, result, turns, source, compat, seed)


def engagement_signals(root: Path, compat: str | None) -> Callable[[str], dict[int, np.ndarray] | None]:
    """Per-sample normalised engagement of a session of ``root`` (for Figure 4), None if unreadable.

    Both layouts: the published one, and the session folders ``nao-trainer run`` writes (a study folder:
    the signal recomputed from the raw EEG, ``data.own``)."""
    dirs = {session_name(layout, d): (layout, d) for layout, d in discover(root).all}

    def signal_of(session: str) -> dict[int, np.ndarray] | None:
        if session not in dirs:
            return None
        layout, folder = dirs[session]
        try:
            eng = (session_engagement(folder, compat=compat) if layout == "published"
                   else own_session_engagement(folder))
        except DataError:
            return None
        return {turn: np.asarray(s.normalised, dtype=float) for turn, s in eng.series.items()}

    return signal_of
