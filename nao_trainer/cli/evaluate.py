"""`nao-trainer evaluate`: compare policies (baselines, oracle, trained learners) on simulated users."""
from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.cli import ceiling_report
from nao_trainer.cli._checks import make_output_dir, require_matplotlib

MDPS = ("paper", "informed")  # core.mdps.NAMES, repeated so that --help does not import numpy
ROWS_FILE = "evaluation_rows.csv.gz"
PERSONALISE_ROWS_FILE = "personalise_rows.csv.gz"
PERSONALISE_ROW_COLUMNS = ("user", "cluster", "user_best_level", "policy", "assessment", "score", "engagement",
                           "success", "regret", "samples", "switches", "matched", "level", "visits_1", "visits_2",
                           "visits_3", "visits_4")
ROW_COLUMNS = ("user", "cluster", "policy", "seed", "score", "engagement", "success", "regret", "samples",
               "visits_l1", "visits_l2", "visits_l3", "visits_l4")


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate", help="compare policies on simulated users: exact scores, regret vs the per-user optimum",
        description="Evaluate baselines (fixed levels, staircases, random, best fixed level), the optimum and "
                    "Q-learners (trained on each user's training simulator, frozen and still learning) on a "
                    "user set. Writes DIR/evaluation.json, DIR/evaluation.csv and DIR/evaluation.png. "
                    "See docs/evaluation.md.")
    p.add_argument("--policies", default=None,
                   help="comma-separated policies (default: all baselines, usp:METHOD and usp-learning:METHOD "
                        "for every method, oracle); see docs/evaluation.md")
    p.add_argument("--users", default="clusters",
                   help="clusters | level-only | sessions | DATASET_ROOT (per-session users, leave-one-session-out)")
    p.add_argument("--data", type=Path, default=None, help="dataset root or turn table for --users sessions")
    p.add_argument("--models", type=Path, default=None,
                   help="folder of fitted user models (default: $NAO_TRAINER_MODELS or sim/models)")
    p.add_argument("--mdp", choices=MDPS, default="paper",
                   help="decision process: paper (outcome of the last turn hidden) or informed (default paper)")
    p.add_argument("--policy-files", type=Path, default=None, metavar="DIR",
                   help="use the trained policy files in DIR (e.g. sim/policies) for usp policies on cluster users "
                        "instead of training them here")
    p.add_argument("--seeds", type=int, default=10, help="trained learners per (user, method) (default 10)")
    p.add_argument("--episodes", type=int, default=10_000, help="training episodes per learner (default 10000)")
    p.add_argument("--mc-episodes", type=int, default=1000,
                   help="Monte Carlo episodes per (user, seed) for staircases and still-learning learners (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--workers", type=int, default=2, help="local worker processes (default 2)")
    p.add_argument("--backend", default=None, help="local (default) or dask://HOST:PORT (a running dask scheduler)")
    p.add_argument("--limit", type=int, default=None, help="only the first N sessions (a quick look)")
    p.add_argument("--out", type=Path, default=Path("evaluation"), help="output folder (default ./evaluation)")
    p.add_argument("--no-plots", action="store_true", help="skip the figure")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--per-user", action="store_true",
                   help="also print each user's mean score per policy (mean over seeds)")
    g = p.add_argument_group("personalisation (docs/personalisation.md)")
    g.add_argument("--personalise", action="store_true",
                   help="evaluate the personalisation pipeline (assess, match, choose, keep learning) on held-out "
                        "sessions against always level 2, the best fixed level, a generic policy, the paper's "
                        "pipeline and the per-user oracle; needs --users sessions --data DATASET_ROOT")
    g.add_argument("--assessment", default="0-12", metavar="LENGTHS",
                   help="assessment lengths to compare, e.g. 0-12 or 0,6,12 (default 0-12)")
    g.add_argument("--kappa", type=float, default=10.0,
                   help="strength (pseudo-turns) of the per-level Beta priors; inf: no per-level learning (default 10)")
    g.add_argument("--margin", type=float, default=0.5,
                   help="anti-flip-flop margin: points of expected value a new policy must gain (default 0.5)")
    g.add_argument("--session-prior", default="data", metavar="data|K",
                   help="shrinkage of each held-out session's success per level toward its cluster: 'data' (the "
                        "Beta prior of --users sessions, strength estimated from the data; default) or K pseudo-turns "
                        "(e.g. 2: the session's own rates)")
    g.add_argument("--export-users", type=Path, default=None, metavar="DIR",
                   help="also write every held-out session's user simulator to DIR (usable as --user-model FILE)")
    ceiling_report.add_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    if getattr(args, "user_models", False):
        return ceiling_report.run_user_models(args)
    if getattr(args, "personalise", False):
        return run_personalise(args)
    from nao_trainer.learn import comparison, users
    from nao_trainer.learn.parallel import check_backend

    policies = tuple(s.strip() for s in args.policies.split(",") if s.strip()) if args.policies else \
        comparison.DEFAULT_POLICIES
    if not policies:
        raise ConfigError("--policies: give at least one policy")
    spec = comparison.EvalSpec(policies=policies, process=args.mdp, seeds=args.seeds, episodes=args.episodes,
                               mc_episodes=args.mc_episodes, seed=args.seed)
    ceiling_report.check(args)
    check_backend(args.backend)
    if args.workers < 1 or (args.limit is not None and args.limit < 1):
        raise ConfigError("--workers and --limit must be >= 1")
    require_matplotlib(not args.no_plots)
    make_output_dir(args.out)
    t0 = time.perf_counter()
    kind, user_list = users.load_users(args.users, args.models, args.data, args.workers, args.backend, args.seed,
                                       args.limit)
    given = None
    if args.policy_files is not None:
        if kind != "clusters" and kind != "level-only":
            raise ConfigError("--policy-files applies to cluster users only (sessions are left out of training)")
        given = comparison.policy_file_learners(user_list, args.policy_files, spec)
    print(f"evaluate: {len(user_list)} {kind} users x {len(policies)} policies, {args.mdp} MDP", file=sys.stderr)
    rows = comparison.run(user_list, spec, args.workers, args.backend, given)
    summary = comparison.summarise(rows)
    argv = getattr(args, "argv", None) or ["evaluate"]
    report = {
        "command": "nao-trainer " + " ".join(shlex.quote(a) for a in argv),
        "users": kind, "n_users": len(user_list), "mdp": args.mdp,
        "spec": {"policies": list(policies), "seeds": spec.seeds, "episodes": spec.episodes,
                 "mc_episodes": spec.mc_episodes, "turns": spec.turns, "seed": spec.seed,
                 "hyperparameters": spec.config.to_dict(),
                 "policy_files": None if args.policy_files is None else str(args.policy_files)},
        "summary": summary, "claims": comparison.claims(rows), "rows_file": ROWS_FILE,
    }
    report["ceiling"] = ceiling_report.comparison_section(args, user_list, rows, spec.turns)
    report["seconds"] = round(time.perf_counter() - t0, 2)
    from nao_trainer.files import write_json_atomic, write_text_atomic

    out = Path(args.out)
    write_json_atomic(out / "evaluation.json", report)
    write_text_atomic(out / "evaluation.csv", to_csv(summary))
    write_rows(rows, out / ROWS_FILE)
    paths = [out / "evaluation.json", out / "evaluation.csv", out / ROWS_FILE]
    if not args.no_plots:
        from nao_trainer.plots.evaluation import plot_evaluation

        title = f"{kind} users ({len(user_list)}), {args.mdp} MDP: means and 95 % CIs over users and seeds"
        paths.append(plot_evaluation(summary, title, out / "evaluation.png"))
    if args.json:
        print(json.dumps(report))
    else:
        print(format_table(summary, report["claims"]))
        print(ceiling_report.format_section(report["ceiling"]))
        if args.per_user:
            print(per_user_table(rows))
        for path in paths:
            print(f"  {path}")
    return 0


def _ci(v, digits=2) -> str:
    return "n/a" if v is None else f"[{v[0]:.{digits}f}, {v[1]:.{digits}f}]"


def format_table(summary: list[dict], claims: list[dict]) -> str:
    """The summary as aligned text; d best-fixed = paired score difference to the best fixed level."""
    lines = [f"{'policy':<26} {'n':>4} {'score':>7} {'95% CI':>17} {'engage':>7} {'success':>7} "
             f"{'regret':>7} {'95% CI':>17} {'d best-fixed':>13} {'95% CI':>17}"]
    for s in summary:
        ref = s.get("vs_reference")
        d = "" if ref is None else f"{ref['score_diff']:+.2f}"
        dci = "" if ref is None else _ci(ref["score_diff_ci"])
        lines.append(f"{s['policy']:<26} {s['n']:>4} {s['score']:7.2f} {_ci(s['score_ci']):>17} {s['engagement']:7.3f} "
                     f"{s['success']:7.3f} {s['regret']:7.2f} {_ci(s['regret_ci']):>17} {d:>13} {dci:>17}")
    if claims:
        lines.append("engagement feedback vs the performance-only learner (paired over users x seeds):")
        for c in claims:
            lines.append(f"  {c['a']:<22} - {c['b']:<26} score {c['score_diff']:+.2f} {_ci(c['score_diff_ci'])}  "
                         f"engagement {c['engagement_diff']:+.4f} {_ci(c['engagement_diff_ci'], 4)}")
    return "\n".join(lines)


def per_user_table(rows: list[dict]) -> str:
    """Mean score over seeds of every (user, policy): one line per policy, one column per user."""
    import numpy as np

    user_names = list(dict.fromkeys(r["user"] for r in rows))
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    lines = ["score per user (mean over seeds): " + ", ".join(user_names)]
    for pol in policies:
        vals = [np.mean([r["score"] for r in rows if r["user"] == u and r["policy"] == pol]) for u in user_names]
        lines.append(f"  {pol:<26} " + " ".join(f"{v:7.2f}" for v in vals))
    return "\n".join(lines)


def write_rows(rows: list[dict], path: Path) -> None:
    """Every (user, policy, seed) row as gzip CSV (mtime 0: the same run gives the same bytes)."""
    import gzip
    import os

    lines = [",".join(ROW_COLUMNS)]
    for r in rows:
        vals = [r["user"], r["cluster"], r["policy"], "" if r["seed"] is None else r["seed"], repr(r["score"]),
                repr(r["engagement"]), repr(r["success"]), repr(r["regret"]), r["samples"], *r["visits"]]
        lines.append(",".join(str(v) for v in vals))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0, filename="") as fh:
        fh.write(("\n".join(lines) + "\n").encode())
    os.replace(tmp, path)


def read_rows(path: Path) -> list[dict]:
    """Rows written by ``write_rows`` (numbers as floats, seed None for baselines)."""
    import csv
    import gzip

    with gzip.open(path, "rt") as fh:
        out = []
        for r in csv.DictReader(fh):
            row = {k: r[k] for k in ("user", "cluster", "policy")}
            row["seed"] = None if r["seed"] == "" else int(r["seed"])
            for k in ("score", "engagement", "success", "regret"):
                row[k] = float(r[k])
            row["samples"] = int(r["samples"])
            row["visits"] = [float(r[f"visits_l{i}"]) for i in (1, 2, 3, 4)]
            out.append(row)
    return out


def to_csv(summary: list[dict]) -> str:
    cols = ["policy", "n", "users", "score", "score_lo", "score_hi", "engagement", "engagement_lo", "engagement_hi",
            "success", "regret", "regret_lo", "regret_hi", "d_best_fixed", "d_best_fixed_lo", "d_best_fixed_hi"]
    lines = [",".join(cols)]
    for s in summary:
        ref = s.get("vs_reference") or {}

        def lo_hi(ci):
            return ("", "") if not ci else (f"{ci[0]:.6g}", f"{ci[1]:.6g}")

        vals = [s["policy"], s["n"], s["users"], f"{s['score']:.6g}", *lo_hi(s["score_ci"]), f"{s['engagement']:.6g}",
                *lo_hi(s["engagement_ci"]), f"{s['success']:.6g}", f"{s['regret']:.6g}", *lo_hi(s["regret_ci"]),
                "" if not ref else f"{ref['score_diff']:.6g}", *lo_hi(ref.get("score_diff_ci"))]
        lines.append(",".join(str(v) for v in vals))
    return "\n".join(lines) + "\n"


def run_personalise(args) -> int:
    """``evaluate --personalise``: the pipeline on leave-one-session-out users (learn.personalise)."""
    from nao_trainer.files import write_json_atomic, write_text_atomic
    from nao_trainer.learn import artifacts, personalise
    from nao_trainer.learn.parallel import check_backend

    if args.users not in ("sessions",) and not Path(args.users).exists():
        raise ConfigError("--personalise evaluates on held-out sessions: use --users sessions --data DATASET_ROOT")
    source = args.data if args.users == "sessions" else Path(args.users)
    if source is None:
        raise ConfigError("--personalise needs the dataset: add --data DATASET_ROOT")
    if args.policies:
        raise ConfigError("--personalise compares a fixed set of policies; drop --policies")
    try:
        session_prior = None if args.session_prior == "data" else float(args.session_prior)
    except ValueError:
        raise ConfigError(f"--session-prior must be 'data' or a number of pseudo-turns, got {args.session_prior!r}") from None
    spec = personalise.PersonaliseSpec(lengths=personalise.parse_lengths(args.assessment), kappa=args.kappa,
                                       session_prior=session_prior,
                                       margin=args.margin, episodes=args.episodes, seeds=1,
                                       mc_episodes=args.mc_episodes, seed=args.seed)
    ceiling_report.check(args)
    check_backend(args.backend)
    if args.workers < 1 or (args.limit is not None and args.limit < 1):
        raise ConfigError("--workers and --limit must be >= 1")
    require_matplotlib(not args.no_plots)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        if args.export_users is not None:
            Path(args.export_users).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{exc.filename}: cannot create the folder ({exc.strerror}); choose another") from None
    manifest = artifacts.load_manifest(args.models)
    t0 = time.perf_counter()
    print(f"evaluate --personalise: held-out sessions of {source}, assessment lengths {list(spec.lengths)}",
          file=sys.stderr)
    result = personalise.run(source, spec, manifest.get("compat"), int(manifest.get("k", 3)), workers=args.workers,
                             backend=args.backend, limit=args.limit)
    summary = personalise.summarise(result["rows"])
    engagement = personalise.summarise_engagement(result["engagement"])
    argv = getattr(args, "argv", None) or ["evaluate", "--personalise"]
    report = {"command": "nao-trainer " + " ".join(shlex.quote(a) for a in argv),
              "users": "sessions (leave-one-session-out)", "n_users": len(result["users"]),
              "spec": {"lengths": list(spec.lengths), "levels": list(spec.levels), "kappa": spec.kappa,
                       "session_prior": "data" if spec.session_prior is None else spec.session_prior,
                       "margin": spec.margin, "method": spec.method, "episodes": spec.episodes,
                       "mc_episodes": spec.mc_episodes, "turns": spec.turns, "seed": spec.seed},
              "summary": summary, "engagement_information": engagement, "rows_file": PERSONALISE_ROWS_FILE,
              "ceiling": ceiling_report.personalise_section(args, result, spec.turns)}
    report["seconds"] = round(time.perf_counter() - t0, 2)
    write_json_atomic(out / "personalise.json", report)
    write_text_atomic(out / "personalise.csv", personalise_csv(summary))
    write_personalise_rows(result["rows"], out / PERSONALISE_ROWS_FILE)
    paths = [out / "personalise.json", out / "personalise.csv", out / PERSONALISE_ROWS_FILE]
    if args.export_users is not None:
        for user in result["users"]:
            name = user["name"].removeprefix("session:").replace("/", "_")
            write_json_atomic(Path(args.export_users) / f"{name}.json", user)
        paths.append(Path(args.export_users))
    if not args.no_plots:
        from nao_trainer.plots.personalise import plot_personalise

        prior = "Beta prior from the data" if spec.session_prior is None else f"own rates, prior {spec.session_prior:g} turns"
        title = (f"{len(result['users'])} held-out sessions (leave-one-session-out; {prior}): "
                 "means and 95 % CIs over users")
        paths.append(plot_personalise(summary, title, out / "personalise.png"))
    if args.json:
        print(json.dumps({k: v for k, v in report.items() if k != "rows"}))
    else:
        print(format_personalise(summary, engagement))
        print(ceiling_report.format_section(report["ceiling"]))
        for path in paths:
            print(f"  {path}")
    return 0


def _share(g: dict) -> str:
    if g.get("share") is None:
        return "n/a"
    return f"{g['share']:+.2f} {_ci(g['share_ci'])}"


def format_personalise(summary: list[dict], engagement: list[dict]) -> str:
    """The personalisation summary as aligned text (d best-fixed: paired score difference)."""
    lines = [f"{'policy':<14} {'A':>3} {'score':>7} {'95% CI':>17} {'d best-fixed':>13} {'95% CI':>17} "
             f"{'gap closed':>24} {'matched':>8}"]
    for s in summary:
        a = "" if s["assessment"] is None else str(s["assessment"])
        d = "" if s["d_reference"] is None else f"{s['d_reference']:+.2f}"
        m = f"{s['matched']:.2f}" if "matched" in s else ""
        lines.append(f"{s['policy']:<14} {a:>3} {s['score']:7.2f} {_ci(s['score_ci']):>17} {d:>13} "
                     f"{_ci(s['d_reference_ci']):>17} {_share(s['gap_closed']):>24} {m:>8}")
    if engagement:
        lines.append("does engagement help the match? (real turns of each held-out session; P = P(its cluster))")
        for e in engagement:
            a, b = e["outcomes"], e["outcomes+engagement"]
            lines.append(f"  first {e['turns']:2d} turns: outcomes only {a['accuracy']:.2f} right, P {a['p_true']:.2f}; "
                         f"with engagement {b['accuracy']:.2f} right, P {b['p_true']:.2f}; "
                         f"diff P {e['p_true_diff']:+.3f} {_ci(e['p_true_diff_ci'], 3)}")
    return "\n".join(lines)


def personalise_csv(summary: list[dict]) -> str:
    cols = ["policy", "assessment", "users", "score", "score_lo", "score_hi", "d_best_fixed", "d_best_fixed_lo",
            "d_best_fixed_hi", "gap_closed", "gap_closed_lo", "gap_closed_hi", "regret", "matched", "switches"]
    lines = [",".join(cols)]
    for s in summary:
        def lo_hi(ci):
            return ("", "") if not ci else (f"{ci[0]:.6g}", f"{ci[1]:.6g}")

        g = s["gap_closed"]
        vals = [s["policy"], "" if s["assessment"] is None else s["assessment"], s["users"], f"{s['score']:.6g}",
                *lo_hi(s["score_ci"]), "" if s["d_reference"] is None else f"{s['d_reference']:.6g}",
                *lo_hi(s["d_reference_ci"]), "" if g.get("share") is None else f"{g['share']:.6g}",
                *lo_hi(g.get("share_ci")), f"{s['regret']:.6g}", s.get("matched", ""), s.get("switches", "")]
        lines.append(",".join(str(v) for v in vals))
    return "\n".join(lines) + "\n"


def write_personalise_rows(rows: list[dict], path: Path) -> None:
    """Every (user, policy, assessment length) row of ``--personalise`` as gzip CSV (same bytes for the same run)."""
    import gzip
    import os

    lines = [",".join(PERSONALISE_ROW_COLUMNS)]
    for r in rows:
        vals = [r.get(k) for k in PERSONALISE_ROW_COLUMNS[:-4]] + list(r["visits"])
        lines.append(",".join("" if v is None else repr(v) if isinstance(v, float) else str(v) for v in vals))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0, filename="") as fh:
        fh.write(("\n".join(lines) + "\n").encode())
    os.replace(tmp, path)
