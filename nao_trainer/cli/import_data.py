"""`nao-trainer import DATASET_ROOT --out FILE`: the published sessions as one tidy turn table (CSV)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nao_trainer.cli._filters import add_filter_args, filter_from_args

#: Exit code of an import that wrote its table but skipped sessions (a script can tell; docs/reference/data.md).
EXIT_SKIPPED = 6
from nao_trainer.errors import ConfigError


def register(sub) -> None:
    p = sub.add_parser(
        "import",
        help="read recorded sessions (yours or the published ones) into one turn table (CSV)",
        description="Read every session under ROOT into one CSV with a row per turn, plus FILE.json with "
        "provenance: session folders written by `nao-trainer run` (a study folder holding many, or one), and "
        "user_<id>/session_<k>/ folders of the published layout. Sessions that cannot be read are reported one "
        "line each and skipped; interrupted or invalid turns are left out of the table with the reason. "
        "Exit 0 when every session imported; 6 when the table was written but some sessions were skipped "
        "(--allow-skipped: 0); 2 when none imported. Schema: docs/reference/data.md.",
    )
    p.add_argument("root", metavar="ROOT", type=Path, help="study folder, dataset root, or one session folder")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="FILE", help="CSV file to write")
    p.add_argument("--compat", choices=["authors2018"], default=None,
                   help="compute per-turn engagement exactly as the dataset's authors did")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="per-session cache folder (default: FILE.cache beside the output)")
    p.add_argument("--no-cache", action="store_true", help="read every session again")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    add_filter_args(p)
    p.add_argument("--allow-skipped", action="store_true",
                   help="exit 0 even when sessions were skipped (they are still listed)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.data.dataset import cache_dir, import_dataset
    from nao_trainer.data.turn_table import write_table

    if args.out.is_dir():  # said before anything is read (it failed after the import, naming a temp file)
        raise ConfigError(f"--out {args.out}: is a folder; give the CSV file to write, e.g. {args.out / 'turns.csv'}")
    folder = args.out.resolve().parent
    if not folder.is_dir() and not folder.parent.is_dir():  # the output's own folder is made, never a whole tree
        raise ConfigError(f"--out {args.out}: the folder {folder.parent} does not exist (a typo?); create it first "
                          "or choose another")
    cache = None if args.no_cache else (args.cache or cache_dir(args.root, args.compat, beside=args.out))
    progress = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    result = import_dataset(args.root, compat=args.compat, cache_dir=cache, progress=progress,
                            select=filter_from_args(args))
    for line in report_lines(result):
        print(f"nao-trainer import: {line}", file=sys.stderr)
    write_table(result.table, args.out, result.provenance)
    t = result.table
    print(f"nao-trainer import: {t.mix()}", file=sys.stderr)
    skipped = len(result.problems)
    print(f"{args.out}: {len(t)} turns from {len(t.sessions)} sessions"
          f" ({result.cached} from cache, {skipped} skipped)"
          + (f"; exit {EXIT_SKIPPED}: {skipped} sessions were skipped (listed above; --allow-skipped exits 0)"
             if skipped and not args.allow_skipped else ""), file=sys.stderr)
    return EXIT_SKIPPED if skipped and not args.allow_skipped else 0


def report_lines(result) -> list[str]:
    """One line per session left out, per note, and the count of turns left out (with each turn)."""
    lines = [str(p) for p in result.problems] + list(result.notes)
    summary = result.excluded_summary()
    if summary:
        lines.append(summary + ":")
        lines += [f"  {e}" for e in result.excluded]
    return lines

