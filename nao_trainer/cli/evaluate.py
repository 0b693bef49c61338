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
from nao_trainer.learn.parallel import check_backend
from nao_trainer.session.config import load_config

MDPS = ("paper", "informed")  # core.processes.NAMES, repeated so that --help does not import numpy


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate", help="compare policies on simulated users: exact scores, regret vs the per-user optimum",
        description="Evaluate baselines (fixed levels, staircases, random, best fixed level), the optimum and "
                    "Q-learners (trained on each user's training simulator, frozen and still learning) on a "
                    "user set. Writes DIR/evaluation.json, DIR/evaluation.csv and DIR/evaluation.png. "
                    "See docs/explanation/evaluation.md.")
    p.add_argument("--policies", default=None,
                   help="comma-separated policies (default: all baselines, usp:METHOD and usp-learning:METHOD "
                        "for every method, oracle); see docs/explanation/evaluation.md")
    p.add_argument("--users", default=None,
                   help="clusters | level-only | sessions | DATASET_ROOT (per-session users, each fitted without its person) | "
                        "task (the --task's own simulated users); default clusters, with --task nback: task")
    p.add_argument("--task", metavar="NAME", default=None,
                   help="the task the users play (nao-trainer plugins lists them); default the sequence task, whose "
                        "participants the fitted user sets are; nback: its signal-detection observers (docs/explanation/evaluation.md)")
    p.add_argument("--turns", type=int, default=25, help="turns per session (default 25, the paper's)")
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
    g = p.add_argument_group("personalisation (docs/explanation/personalisation.md)")
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


def _task_users(args) -> tuple[object | None, str]:
    """The ``--task`` (None without one) and the user set: ``--users``, else the task's own simulated users for a
    task the published data are not of (``Task.published_data``), else the fitted clusters. One line when a user
    set does not belong to the task."""
    if args.task is None:
        return None, args.users or "clusters"
    from nao_trainer.tasks.base import task_named

    task = task_named(args.task)
    ours = bool(getattr(task, "published_data", False))  # the fitted users and the dataset are this task's
    which = args.users or ("clusters" if ours else "task")
    if which != "task" and not ours:
        raise ConfigError(f"--users {which}: the fitted user sets and the dataset are people playing the sequence "
                          f"task (the published data); task {task.name!r} is evaluated on its own simulated users "
                          "(--users task, its default)")
    if which == "task" and getattr(task, "simulated_users", None) is None:
        raise ConfigError(f"--users task: task {task.name!r} declares no simulated users (Task.simulated_users)")
    if not ours and (args.personalise or args.user_models or args.policy_files is not None):
        flag = "--personalise" if args.personalise else "--user-models" if args.user_models else "--policy-files"
        raise ConfigError(f"{flag} works on the published data, which are the sequence task's; task {task.name!r} "
                          "has no sessions to hold out or fit (evaluate it on its simulated users)")
    return task, which


def run(args) -> int:
    task, which = _task_users(args)
    args.users = which
    if getattr(args, "user_models", False):
        return ceiling_report.run_user_models(args)
    if getattr(args, "personalise", False):
        return run_personalise(args)
    from nao_trainer.experiments import comparison, reports
    from nao_trainer.learn import users

    policies = tuple(s.strip() for s in args.policies.split(",") if s.strip()) if args.policies else \
        comparison.DEFAULT_POLICIES
    if not policies:
        raise ConfigError("--policies: give at least one policy")
    spec = comparison.EvalSpec(policies=policies, process=args.mdp, turns=args.turns, seeds=args.seeds,
                               episodes=args.episodes, mc_episodes=args.mc_episodes, seed=args.seed)
    ceiling_report.check(args)
    check_backend(args.backend)
    if args.workers < 1 or (args.limit is not None and args.limit < 1):
        raise ConfigError("--workers and --limit must be >= 1")
    require_matplotlib(not args.no_plots)
    make_output_dir(args.out)
    t0 = time.perf_counter()
    if which == "task":
        engagement = load_config(None).participant_model.engagement_by_level  # the demo's (the task models none)
        kind, user_list = f"task {task.name}", users.task_user_set(task, engagement)[:args.limit]
        print(f"evaluate: task {task.name}, levels {', '.join(map(str, task.levels))}: its own simulated users "
              f"({', '.join(u.name for u in user_list)}); not fitted to people (the published data are the sequence "
              "task's)", file=sys.stderr)
    else:
        kind, user_list = users.load_users(args.users, args.models, args.data, args.workers, args.backend, args.seed,
                                           args.limit)
    given = None
    if args.policy_files is not None:
        if kind != "clusters" and kind != "level-only":
            raise ConfigError("--policy-files applies to cluster users only (sessions are left out of training)")
        given = comparison.policy_file_learners(user_list, args.policy_files, spec)
    print(f"evaluate: {len(user_list)} {kind} users x {len(policies)} policies, {args.mdp} MDP", file=sys.stderr)
    rows = comparison.run(user_list, spec, args.workers, args.backend, given)
    ceiling = ceiling_report.comparison_section(args, user_list, rows, spec.turns)
    report, paths = reports.write_comparison(Path(args.out), rows, spec, command=_command(args, ["evaluate"]),
                                             users=kind, n_users=len(user_list), policy_files=args.policy_files,
                                             started=t0, extra={"ceiling": ceiling}, by_person=which == "sessions")
    if not args.no_plots:
        from nao_trainer.plots.evaluation import plot_evaluation

        over = f"{report['summary'][0]['people']} people" if report["summary"][0].get("unit") == "people" else \
            "users and seeds"
        title = f"{kind} users ({len(user_list)}), {args.mdp} MDP: means and 95 % CIs over {over}"
        paths.append(plot_evaluation(report["summary"], title, Path(args.out) / "evaluation.png"))
    if args.json:
        print(json.dumps(report))
    else:
        print(reports.format_table(report["summary"], report["claims"]))
        print(ceiling_report.format_section(report["ceiling"]))
        if args.per_user:
            print(reports.per_user_table(rows))
        for path in paths:
            print(f"  {path}")
    return 0


def _command(args, default: list[str]) -> str:
    """The command line as parsed (recorded in the report)."""
    return "nao-trainer " + " ".join(shlex.quote(a) for a in (getattr(args, "argv", None) or default))


def run_personalise(args) -> int:
    """``evaluate --personalise``: the pipeline on per-session users, each fitted without its person (experiments.personalisation)."""
    from nao_trainer.experiments import personalisation, reports
    from nao_trainer.learn import artifacts

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
    spec = personalisation.PersonaliseSpec(lengths=personalisation.parse_lengths(args.assessment), kappa=args.kappa,
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
    result = personalisation.run(source, spec, manifest.get("compat"), int(manifest.get("k", 3)),
                                 workers=args.workers, backend=args.backend, limit=args.limit)
    ceiling = ceiling_report.personalise_section(args, result, spec.turns)
    report, paths = reports.write_personalisation(out, result, spec, command=_command(args, ["evaluate", "--personalise"]),
                                                  started=t0, export_users=args.export_users,
                                                  extra={"ceiling": ceiling})
    if not args.no_plots:
        from nao_trainer.plots.personalise import plot_personalise

        prior = "Beta prior from the data" if spec.session_prior is None else f"own rates, prior {spec.session_prior:g} turns"
        title = (f"{len(result['users'])} held-out sessions of {report['summary'][0]['people']} people "
                 f"(leave-one-person-out; {prior}): means and 95 % CIs over people")
        paths.append(plot_personalise(report["summary"], title, out / "personalise.png"))
    if args.json:
        print(json.dumps(report))
    else:
        print(reports.format_personalise(report["summary"], report["engagement_information"]))
        print(ceiling_report.format_section(report["ceiling"]))
        for path in paths:
            print(f"  {path}")
    return 0
