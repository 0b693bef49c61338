"""`nao-trainer train`: learn user-specific policies on the simulated users (paper Figures 7 and 8)."""
from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import cannot_write
from nao_trainer.cli._checks import make_output_dir, require_matplotlib

#: ``core.qlearning.METHODS``, repeated here so that ``--help`` does not import numpy (a test keeps them equal).
METHODS = ("performance", "shaping", "qaug")


def register(sub) -> None:
    p = sub.add_parser(
        "train", help="train user-specific policies (Q-learning with engagement feedback) on simulated users",
        description="Train one Q-learner per (user model, method, seed) and write learning curves, policies at "
                    "S0, the policy files and a summary. See docs/explanation/policies.md.")
    p.add_argument("--models", type=Path, default=None,
                   help="folder of fitted user models (default: $NAO_TRAINER_MODELS or sim/models)")
    p.add_argument("--methods", default=",".join(METHODS),
                   help=f"comma-separated methods among {', '.join(METHODS)} (default: all)")
    p.add_argument("--seeds", type=int, default=20, help="independent runs per (model, method) (default 20)")
    p.add_argument("--episodes", type=int, default=10_000, help="episodes per run (default 10000)")
    p.add_argument("--turns", type=int, default=25, help="turns per episode (default 25, as in the study)")
    p.add_argument("--seed", type=int, default=0, help="base seed; same seed, same outputs (default 0)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--mdp", choices=("paper", "informed"), default="paper",
                   help="decision process: paper (outcome of the last turn hidden) or informed (default paper)")
    p.add_argument("--backend", default=None, help="local (default) or dask://HOST:PORT (a running dask scheduler)")
    p.add_argument("--out", type=Path, default=Path("trained_policies"),
                   help="output folder (default ./trained_policies; the shipped ones are in sim/policies)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from nao_trainer.learn import artifacts
    from nao_trainer.learn.training import TrainingSpec, train_grid, write_outputs

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    try:
        spec = TrainingSpec(methods=methods, seeds=args.seeds, episodes=args.episodes, turns=args.turns,
                            seed=args.seed, workers=args.workers, process=args.mdp, backend=args.backend)
    except ValueError as exc:  # its messages start with the field, which is the option's name
        raise ConfigError(f"--{exc}") from None
    require_matplotlib(not args.no_plots)
    created = not Path(args.out).exists()
    try:  # the folder is made inside: a Ctrl-C just after mkdir (a loaded machine, seen) leaves none behind
        make_output_dir(args.out)
        models_dir = Path(args.models) if args.models else artifacts.default_models_dir()
        clusters = artifacts.available_models(models_dir)
        if not clusters:
            raise DataError(f"{models_dir / artifacts.MANIFEST}: lists no clusters; refit with `nao-trainer fit`")
        simulators = [artifacts.load_simulator(c, models_dir) for c in clusters]
        result = train_grid(simulators, clusters, spec, progress=True)
    except BaseException:  # interrupted or failed before writing: leave no empty folder behind
        if created:
            _remove_if_empty(Path(args.out))
        raise
    print(f"train: {result.turns / 1e6:.1f} M turns in {result.seconds:.1f} s "
          f"({result.turns / max(result.seconds, 1e-9) / 1e6:.2f} M turns/s); writing {args.out}", file=sys.stderr)
    argv = getattr(args, "argv", None) or ["train"]  # cli.main stores the arguments it parsed
    command = "nao-trainer " + " ".join(shlex.quote(a) for a in argv)
    try:
        paths = write_outputs(result, args.out, str(models_dir), command)
        if not args.no_plots:
            from nao_trainer.plots.learning import write_figures

            paths.update(write_figures(result, args.out))
    except OSError as exc:
        raise DataError(cannot_write(args.out, "outputs", exc, "choose a writable --out")) from None
    if args.json:
        print(json.dumps(result.summary_json()))
    else:
        print_table(result.results())
        for key, path in paths.items():
            print(f"  {key}: {path}")
    return 0


def _remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()  # only ever removes an empty folder
    except OSError:
        pass


def print_table(rows: list[dict]) -> None:
    """The results as an aligned text table (score and engagement over the final episodes).

    The last columns give the difference to the performance-only learner; ``*`` marks a 95 %
    Welch interval that excludes 0.
    """
    def ci(v, digits):
        return "n/a" if v is None else f"[{v[0]:.{digits}f}, {v[1]:.{digits}f}]"

    def diff(row, key, digits):
        d = row.get("vs_performance", {}).get(key)
        if d is None:
            return ""
        return f"{d['diff']:+.{digits}f}{'*' if d['significant'] else ' '}"

    print(f"{'cluster':>7}  {'method':<11}  {'score':>7}  {'95% CI':>16}  {'engagement':>10}  {'95% CI':>16}"
          f"  {'d score':>8}  {'d eng.':>8}")
    for r in rows:
        print(f"{r['cluster']:>7}  {r['method']:<11}  {r['score_mean']:7.2f}  {ci(r['score_ci'], 2):>16}  "
              f"{r['engagement_mean']:10.3f}  {ci(r['engagement_ci'], 3):>16}  {diff(r, 'score_diff', 2):>8}  "
              f"{diff(r, 'engagement_diff', 3):>8}")
    print("d score / d eng.: difference to the performance-only learner (* = 95 % Welch interval excludes 0)")
