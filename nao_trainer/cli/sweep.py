"""`nao-trainer sweep`: hyper-parameter sweeps (beta1, beta2, alpha, ...) on simulated users."""
from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

from nao_trainer.errors import ConfigError
from nao_trainer.cli._checks import make_output_dir, require_matplotlib
from nao_trainer.learn.parallel import check_backend

MDPS = ("paper", "informed")


def register(sub) -> None:
    p = sub.add_parser(
        "sweep", help="sweep Q-learning hyper-parameters; score each point's final policies exactly",
        description="Train learners at every point of a hyper-parameter grid on each user model and evaluate "
                    "their final (frozen) policies exactly. Writes DIR/sweep.json, DIR/sweep.csv and "
                    "DIR/sweep.png. Example: nao-trainer sweep --param beta1=0:10:41. See docs/explanation/evaluation.md.")
    p.add_argument("--param", action="append", default=[], metavar="NAME=START:STOP:COUNT",
                   help="a swept hyper-parameter (repeat for a grid); NAME=V1,V2,... for a list")
    p.add_argument("--method", default=None,
                   help="learning method (default: shaping for beta1, qaug for beta2, else performance)")
    p.add_argument("--users", default="clusters", choices=["clusters", "level-only"],
                   help="user models to train and evaluate on (default clusters)")
    p.add_argument("--models", type=Path, default=None, help="folder of fitted user models (default sim/models)")
    p.add_argument("--mdp", choices=MDPS, default="paper", help="decision process (default paper)")
    p.add_argument("--seeds", type=int, default=20, help="learners per (point, user) (default 20)")
    p.add_argument("--episodes", type=int, default=10_000, help="training episodes per learner (default 10000)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--workers", type=int, default=2, help="local worker processes (default 2)")
    p.add_argument("--backend", default=None, help="local (default) or dask://HOST:PORT (a running dask scheduler)")
    p.add_argument("--out", type=Path, default=Path("sweep"), help="output folder (default ./sweep)")
    p.add_argument("--no-plots", action="store_true", help="skip the figure")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from nao_trainer.experiments import reports, sweep
    from nao_trainer.learn import users

    spec = sweep.make_spec(args.param, args.method, args.seeds, args.episodes, seed=args.seed, process=args.mdp)
    check_backend(args.backend)
    if args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    require_matplotlib(not args.no_plots)
    make_output_dir(args.out)
    _, user_list = users.load_users(args.users, args.models)
    n_points = len(spec.points())
    turns = n_points * len(user_list) * spec.seeds * spec.episodes * spec.turns
    print(f"sweep: {n_points} points x {len(user_list)} users x {spec.seeds} seeds x {spec.episodes} episodes "
          f"({turns / 1e9:.2f} G turns), method {spec.method}, {args.mdp} MDP", file=sys.stderr)
    t0 = time.perf_counter()
    results = sweep.run(spec, user_list, args.workers, args.backend)
    seconds = time.perf_counter() - t0
    argv = getattr(args, "argv", None) or ["sweep"]
    report, lines, paths = reports.write_sweep(Path(args.out), results, spec, seconds=seconds,
                                               command="nao-trainer " + " ".join(shlex.quote(a) for a in argv))
    if not args.no_plots:
        from nao_trainer.plots.evaluation import plot_sweep, plot_sweep_grid

        names = [n for n, _ in spec.params]
        if len(names) == 1:
            paths.append(plot_sweep([{**r, "value": r[names[0]]} for r in results], names[0], Path(args.out) / "sweep.png"))
        elif len(names) == 2:  # two parameters: a heat map per user model
            paths.append(plot_sweep_grid(results, (names[0], names[1]), Path(args.out) / "sweep.png"))
        else:
            print(f"sweep: no sweep.png for {len(names)} swept parameters (a figure shows one or two); "
                  f"sweep.csv holds every point", file=sys.stderr)
    print(f"sweep: {turns / 1e9:.2f} G turns in {seconds:.1f} s ({turns / max(seconds, 1e-9) / 1e6:.1f} M turns/s)",
          file=sys.stderr)
    if args.json:
        print(json.dumps(report))
    else:
        print("\n".join(lines))
        for path in paths:
            print(f"  {path}")
    return 0
