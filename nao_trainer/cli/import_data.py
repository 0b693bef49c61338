"""`nao-trainer import DATASET_ROOT --out FILE`: the published sessions as one tidy turn table (CSV)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "import",
        help="read sessions of the published layout into one turn table (CSV)",
        description="Read every user_<id>/session_<k>/ under DATASET_ROOT (logfile, state_EEG, EEG recordings) "
        "into one CSV with a row per turn, plus FILE.json with provenance. Sessions that cannot be read are "
        "reported one line each and skipped. Exit 0 when at least one session imported.",
    )
    p.add_argument("root", metavar="DATASET_ROOT", type=Path, help="dataset root, or one session folder")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="FILE", help="CSV file to write")
    p.add_argument("--compat", choices=["authors2018"], default=None,
                   help="compute per-turn engagement exactly as the dataset's authors did")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="per-session cache folder (default: FILE.cache beside the output)")
    p.add_argument("--no-cache", action="store_true", help="read every session again")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.data.dataset import cache_dir, import_dataset, write_table

    cache = None if args.no_cache else (args.cache or cache_dir(args.root, args.compat, beside=args.out))
    progress = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    result = import_dataset(args.root, compat=args.compat, cache_dir=cache, progress=progress)
    for problem in result.problems:
        print(f"nao-trainer import: {problem}", file=sys.stderr)
    write_table(result.table, args.out, result.provenance)
    t = result.table
    print(f"{args.out}: {len(t)} turns from {len(t.sessions)} sessions"
          f" ({result.cached} from cache, {len(result.problems)} skipped)", file=sys.stderr)
    return 0
