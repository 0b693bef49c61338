"""`nao-trainer study STUDY_DIR`: one row per session (CSV) and a figure comparing the participants."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nao_trainer.errors import DataError
from nao_trainer.files import write_text_atomic


def register(sub) -> None:
    p = sub.add_parser(
        "study",
        help="a study table: one row per session written by `run` (CSV + figure)",
        description="Read every session folder written by `nao-trainer run` under STUDY_DIR and write "
        "study.csv (session, pseudonym, date, turns, score, success per level, mean engagement, turns with EEG, "
        "policy, status, duration) and study.png (score and engagement per session, level over turns). Sessions that cannot "
        "be read are reported one line each and left out.",
    )
    p.add_argument("root", metavar="STUDY_DIR", type=Path, help="folder holding session folders (session.output)")
    p.add_argument("--out", "-o", type=Path, default=None, metavar="DIR",
                   help="where study.csv and study.png go (default: STUDY_DIR)")
    p.add_argument("--no-figure", action="store_true", help="only the CSV")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.data.study import read_study

    out = args.out or args.root
    study = read_study(args.root)
    for line in study.problems:
        print(f"nao-trainer study: {line}", file=sys.stderr)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "study.csv", study.to_csv())
    except OSError as exc:
        raise DataError(f"{out}: cannot write the study table ({exc.strerror}); give another --out") from None
    print(f"{out / 'study.csv'}: {len(study.sessions)} sessions", file=sys.stderr)
    if not args.no_figure:
        from nao_trainer.plots.study import plot_study

        print(f"{plot_study(study, out / 'study.png')}: figure saved", file=sys.stderr)
    return 0
