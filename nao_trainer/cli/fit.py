"""`nao-trainer fit SOURCE --out DIR`: user models, clusters and per-cluster simulators (+ figures)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from nao_trainer.cli._checks import require_matplotlib
from nao_trainer.cli._filters import add_filter_args, filter_from_args
from nao_trainer.errors import ConfigError


def register(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="fit user models, clusters and per-cluster simulated users from data",
        description="Import SOURCE (a study folder of sessions written by `nao-trainer run`, a dataset root of the "
        "published layout, or a turn table CSV from `nao-trainer import`), compute the "
        "user models [P1..P4, E1..E4], cluster them with K-means and fit one simulated user per cluster. "
        "Writes DIR/manifest.json, DIR/cluster_<id>.json and the figures DIR/users.png, DIR/clusters.png. "
        "Sessions of simulated participants are refused unless --include-simulated (or left out with "
        "--exclude-simulated); --study / --input keep some sessions only.",
    )
    p.add_argument("source", metavar="SOURCE", type=Path, help="study folder, dataset root or turn-table CSV")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="DIR", help="folder for the models and figures")
    p.add_argument("--compat", choices=["authors2018"], default=None,
                   help="per-turn engagement as the authors computed it and the authors' simulators (full state "
                   "regression; reproduces the paper's user models). Default: the project's engagement and "
                   "simulators that keep an effect only where a test supports it (docs/explanation/evaluation.md). For a "
                   "turn-table CSV the mode recorded in its CSV.json applies")
    p.add_argument("--k", type=int, default=3, help="number of clusters (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of K-means, MDS and cross-validation folds")
    p.add_argument("--psychometric", type=Path, default=None, metavar="FILE",
                   help="also fit the pooled psychometric user model (span against sequence length, docs/how-to/session.md) "
                        "on the same turns and write it to FILE; the shipped prior sim/psychometric/pooled.json is "
                        "written this way")
    p.add_argument("--json", action="store_true", help="print the cluster table as JSON on stdout")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="import cache folder (default: ~/.cache/nao-trainer/import/...)")
    p.add_argument("--no-cache", action="store_true", help="read every session again")
    add_filter_args(p)
    p.add_argument("--include-simulated", action="store_true",
                   help="also learn from sessions of simulated participants (refused otherwise: pilots and tests "
                        "only; the manifest records how many)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.core.usermodel import TooFewSessions
    from nao_trainer.learn.fit_source import fit_and_save

    if args.k < 1:
        raise ConfigError(f"--k must be a positive number of clusters, got {args.k}")
    require_matplotlib(not args.no_figures, "--no-figures")
    say = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    try:
        fitted = fit_and_save(args.source, args.out, compat=args.compat, k=args.k, seed=args.seed,
                              cache=None if args.no_cache else (args.cache or "default"), progress=say,
                              select=filter_from_args(args), include_simulated=args.include_simulated,
                              psychometric=args.psychometric)
    except TooFewSessions as exc:
        raise exc.naming("--k") from None
    report = fitted.report
    if not args.no_figures:
        from nao_trainer.plots.usermodels import draw_fit

        report["figures"] = [str(p) for p in draw_fit(fitted, args.out)]
        say(f"figures: {', '.join(report['figures'])}")
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(format_table(report))
    return 0


def format_table(report: dict) -> str:
    head = (f"{'id':>2} {'size':>4}  {'P1..P4':<23}  {'E1..E4':<23}  "
            f"{'RMSE perf':>9} {'(CV)':>6}  {'RMSE eng':>8} {'(CV)':>6}")
    lines = [head]
    for c in report["clusters"]:
        p = " ".join(_num(v, 4, 2) for v in c["p"])
        e = " ".join(_num(v, 4, 2) for v in c["e"])
        lines.append(f"{c['id']:>2} {c['size']:>4}  {p:<23}  {e:<23}  {_num(c['rmse_performance'], 9)} "
                     f"{_num(c['cv_rmse_performance'], 6)}  {_num(c['rmse_engagement'], 8)} "
                     f"{_num(c['cv_rmse_engagement'], 6)}")
    return "\n".join(lines)


def _num(value: float | None, width: int, digits: int = 3) -> str:
    """A report number, or "-" where there is none (a cluster of one session has no cross-validation)."""
    return f"{'-':>{width}}" if value is None else f"{value:>{width}.{digits}f}"
