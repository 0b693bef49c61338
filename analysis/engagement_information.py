"""Recompute only the engagement part of ``evaluate --personalise`` outputs ("does engagement help the match?").

    PYTHONPATH=. python analysis/engagement_information.py --data DATASET_ROOT [--workers N] RESULTS_DIR [...]

RESULTS_DIR: a folder written by ``evaluate --personalise`` (docs/results/personalise*, docs/results/ceiling-*).
The engagement measurements of a held-out session depend on its held-out fits (the models' K, ``--seed``) and
its real turns only: not on ``--objective``, ``--session-prior``, ``--assessment`` or any Monte Carlo setting
(``personalisation.engagement_run``; tests/cli/test_cli_personalise.py proves it writes what the full run
writes). So this recomputes them once per (models, seed) of the folders' recorded commands, about a second per
held-out session instead of the full run's 5-45 minutes, and rewrites each folder's ``engagement_rows.csv`` and
``personalise.json``'s ``engagement_information`` (everything else of the report is kept; the command that
recomputed the engagement part is recorded as ``engagement_command``).
"""
from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from nao_trainer.cli import build_parser
from nao_trainer.experiments import personalisation, reports
from nao_trainer.learn import artifacts


def recorded(folder: Path) -> tuple[Path | None, int]:
    """(--models, --seed) of the ``evaluate --personalise`` command recorded in the folder's report."""
    report = json.loads((Path(folder) / "personalise.json").read_text())
    argv = shlex.split(report["command"])
    if argv[:3] != ["nao-trainer", "evaluate", "--personalise"]:
        raise SystemExit(f"{folder}: not an `evaluate --personalise` output ({report['command'][:60]})")
    args = build_parser().parse_args(argv[1:])
    return args.models, args.seed


def rewrite(data: Path, folders: list[Path], workers: int = 1, limit: int | None = None) -> dict[Path, dict]:
    """Recompute and rewrite the engagement part of every folder; the new reports by folder."""
    groups: dict[tuple[Path | None, int], list[Path]] = {}
    for folder in folders:
        groups.setdefault(recorded(folder), []).append(Path(folder))
    out = {}
    for (models, seed), members in groups.items():
        manifest = artifacts.load_manifest(models)
        meas = personalisation.engagement_run(data, manifest.get("compat"), int(manifest.get("k", 3)), seed=seed,
                                              workers=workers, limit=limit)
        for folder in members:
            command = f"PYTHONPATH=. python analysis/engagement_information.py --data ROOT {folder}"
            out[folder] = reports.rewrite_engagement(folder, meas, command)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the published sessions (DATASET_ROOT)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("folders", type=Path, nargs="+")
    a = ap.parse_args()
    for folder, report in rewrite(a.data, a.folders, a.workers).items():
        print(folder)
        print(reports.format_engagement(report["engagement_information"]))


if __name__ == "__main__":
    main()
