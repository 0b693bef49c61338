"""`nao-trainer engagement SESSION_DIR`: per-turn engagement of recorded sessions (yours or the published ones)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import write_text_atomic


def register(sub) -> None:
    p = sub.add_parser(
        "engagement",
        help="per-turn engagement of a recorded session (yours or the published layout)",
        description="Print one row per turn (turn, engagement_index, engagement, quality, contact, reason) "
        "computed from a session folder: one written by `nao-trainer run` (recomputed from its eeg/raw.csv with "
        "the live monitor's rule and settings), or one of the published layout (user_<id>/session_<k>/ with "
        "state_EEG and EEG/bands_robot_N or raw robot_N recordings). Given a study folder or a dataset root, "
        "every session is computed and a session column is added. Empty values come with the reason.",
    )
    p.add_argument("session", metavar="SESSION_DIR", type=Path,
                   help="a session folder, a study folder of sessions, or a dataset root")
    p.add_argument("--compat", choices=["authors2018"], default=None,
                   help="reproduce the authors' published index_1.csv / normalized_1.csv values exactly")
    p.add_argument("--format", choices=["csv", "json"], default="csv", help="output format (default csv)")
    p.add_argument("--source", choices=["bands", "raw"], default=None,
                   help="Muse band lines, or band powers computed from the raw EEG "
                   "(default: band lines when the session has them)")
    p.add_argument("--fs", type=float, default=None, metavar="HZ",
                   help="sampling rate of raw EEG lines (default 220, the published recordings' rate)")
    p.add_argument("--out", "-o", type=Path, default=None, metavar="FILE", help="write to FILE instead of stdout")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG",
                   help="also save a figure of the per-turn engagement (one session only)")
    p.add_argument("--answer", action="store_true",
                   help="add the answer phase (user_N recordings): answer_index, answer_engagement, ...")
    p.add_argument("--workers", type=int, default=2, help="processes for a dataset root (default 2)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.data.dataset import discover
    from nao_trainer.data.engagement import (EngagementFailure, OfflineSettings, check_options, session_engagement_many,
                                             to_csv, to_json)
    from nao_trainer.data.own import own_session_engagement

    # every option checked before the (long) computation
    check_options(args.compat, args.source, args.answer)
    found = discover(args.session)
    if args.plot and len(found.all) != 1:
        raise ConfigError("--plot needs a single session folder, not a dataset root")
    for opt, path in (("--out", args.out), ("--plot", args.plot)):
        if path is not None and not path.parent.is_dir():
            raise DataError(f"{path}: folder {path.parent} does not exist; create it or give another {opt} path")
    if args.fs is not None and not args.fs > 0:
        raise ConfigError(f"--fs must be > 0 Hz, got {args.fs}")
    if args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    settings = OfflineSettings() if args.fs is None else OfflineSettings(fs=args.fs)

    tty = sys.stderr.isatty()

    def progress(done: int, total: int, sid: str) -> None:
        if total <= 1:
            return
        if tty:  # one line, rewritten in place
            print(f"\r[{done}/{total}] {sid}    ", end="" if done < total else "\n", file=sys.stderr, flush=True)
        elif done % 10 == 0 or done == total:
            print(f"[{done}/{total}] sessions", file=sys.stderr, flush=True)

    problems: list = []
    results = []
    if found.published:
        results = session_engagement_many(args.session, args.compat, args.source, settings, args.workers, progress,
                                          answer=args.answer, problems=problems)
    for path in found.own:
        sid = path.name
        if args.compat or args.source == "bands":
            opt = "--compat authors2018" if args.compat else "--source bands"
            problems.append(EngagementFailure(sid, f"{opt} needs Muse band lines; sessions written by `run` have raw "
                                                "EEG (drop the option)"))
            continue
        try:
            results.append(own_session_engagement(path, answer=args.answer))
        except DataError as exc:
            problems.append(EngagementFailure(sid, str(exc)))
    for prob in problems:
        print(f"nao-trainer engagement: skipped {prob.session}: {prob.message}", file=sys.stderr)
    if not results:
        raise DataError(f"{args.session}: no session could be read ({len(problems)} skipped)")
    many = len(found.all) != 1 or found.all[0][1].resolve() != args.session.resolve()  # a root: a session column
    text = to_json(results, many) if args.format == "json" else to_csv(results, many)
    if args.out:
        try:
            write_text_atomic(args.out, text)
        except OSError as exc:
            raise DataError(f"{args.out}: cannot write ({exc.strerror}); give another --out path") from None
        print(f"{args.out}: {sum(len(r.turns) for r in results)} turns of {len(results)} session(s)", file=sys.stderr)
    else:
        sys.stdout.write(text)
        sys.stdout.flush()
    if args.plot:
        try:
            from nao_trainer.plots.engagement import plot_session

            saved = plot_session(results[0], args.plot)
        except OSError as exc:
            raise DataError(f"{args.plot}: cannot write ({exc.strerror}); give another --plot path") from None
        print(f"{saved}: figure saved", file=sys.stderr)
    return 0
