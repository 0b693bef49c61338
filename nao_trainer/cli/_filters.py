"""The session filter shared by `study`, `import` and `fit`: by study name and by who answered."""
from __future__ import annotations

import argparse


def add_filter_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--study", action="append", default=[], metavar="NAME",
                   help="keep only sessions of this study (study.name; repeat for several)")
    p.add_argument("--input", action="append", default=[], metavar="KIND",
                   help="keep only sessions answered this way: simulated, tactile, keyboard, or published "
                        "(the published dataset); repeat for several")
    p.add_argument("--exclude-simulated", action="store_true",
                   help="leave out sessions whose participant was simulated (input simulated)")


def filter_from_args(args: argparse.Namespace):
    """A ``data.turn_table.SessionFilter`` from the flags, or None when none was given."""
    from nao_trainer.data.turn_table import SessionFilter

    if not (args.study or args.input or args.exclude_simulated):
        return None
    return SessionFilter(tuple(args.study), tuple(args.input), args.exclude_simulated)
