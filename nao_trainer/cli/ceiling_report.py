"""The ceiling section of ``nao-trainer evaluate`` and ``evaluate --personalise`` (experiments.ceiling).

Kept apart from cli/evaluate.py so that the two merge easily: evaluate.py calls ``add_arguments``
and ``comparison_section`` / ``personalise_section`` and prints ``format_section``.
"""
from __future__ import annotations

import sys
from typing import Any

from nao_trainer.errors import ConfigError
from nao_trainer.files import write_json_atomic


def add_arguments(p) -> None:
    g = p.add_argument_group("ceiling and objective (docs/explanation/evaluation.md, 'What can be won')")
    g.add_argument("--objective", default="score", metavar="score|target-p:R|target-rate:R",
                   help="what the policies are judged by: score (equation (1), default), target-p:R (each turn's "
                        "success probability near R, -(p - R)^2 per turn; target:R is its old name) or "
                        "target-rate:R (the session's success rate near R, -H (S/H - R)^2; what staircases aim at)")
    g.add_argument("--loo-bayes", action="store_true",
                   help="also the Bayes planner with the prior made of the other users (one solve per user, "
                        "about 3-5 s each)")
    g.add_argument("--questplus-fitted", action="store_true",
                   help="also QUEST+ with its prior fitted on the other people (one exact run per user, "
                        "about 6 s each)")
    g.add_argument("--multi-session", default=None, metavar="S1,S2,...",
                   help="also value S sessions of the same participant, e.g. 2,5,10 (level-only users)")
    g.add_argument("--no-ceiling", action="store_true", help="skip the Bayes ceiling")
    g.add_argument("--user-models", action="store_true",
                   help="instead: compare the per-level, cluster and pooled psychometric user models by next-turn "
                        "log-likelihood on held-out sessions (needs --data DATASET_ROOT); writes DIR/user_models.json")


def _objective(args):
    from nao_trainer.core.objective import parse

    try:
        return parse(args.objective)
    except ValueError as exc:
        raise ConfigError(f"--objective: {exc}") from None


def _sessions(args) -> tuple[int, ...]:
    if not args.multi_session:
        return ()
    try:
        out = tuple(int(x) for x in str(args.multi_session).split(",") if x.strip())
    except ValueError:
        out = ()
    if not out or min(out) < 1:
        raise ConfigError(f"--multi-session: give session counts >= 1 like 2,5,10, got {args.multi_session!r}")
    return out


def check(args) -> None:
    """Validate the flags before any work starts."""
    _objective(args)
    _sessions(args)


def comparison_section(args, users: list, rows: list[dict], turns: int = 25) -> dict[str, Any] | None:
    """``evaluate``: the ceiling beside the compared policies (level-only users only)."""
    from nao_trainer.experiments import ceiling

    obj = _objective(args)
    if args.no_ceiling:
        return None
    if not all(ceiling.is_level_only(u.truth) for u in users):
        if obj.kind != "score":
            raise ConfigError(f"--objective {obj}: needs level-only users (--users level-only or sessions); these "
                              "users' success depends on more than the level")
        return {"note": "no Bayes ceiling: these users' success depends on more than the level "
                        "(use --users level-only or sessions)"}
    rates, train, clusters = ceiling.comparison_inputs(users)
    return _section(args, obj, rows, rates, train, clusters, None, turns)


def personalise_section(args, result: dict, turns: int = 25) -> dict[str, Any] | None:
    """``evaluate --personalise``: the ceiling, ``bayes`` with the fitted clusters as prior,
    ``bayes-psychometric`` with the pooled psychometric model fitted on the other sessions as prior,
    and (``--loo-bayes``) the planner knowing the other users."""
    from nao_trainer.experiments import ceiling

    obj = _objective(args)
    if args.no_ceiling:
        return None
    rates, train, clusters, priors = ceiling.personalise_inputs(result)
    section = _section(args, obj, result["rows"], rates, train, clusters, priors, turns)
    counts = {n: f["counts"] for n, f in result["fits"].items() if "counts" in f}
    if counts:  # the own-rates oracle beside the one the beta-binomial spread of true rates supports
        section["noise_corrected_oracle"] = ceiling.noise_corrected_oracle(counts, obj, turns)
    return section


def _section(args, obj, rows, rates, train, clusters, priors, turns) -> dict[str, Any]:
    from nao_trainer.experiments import ceiling

    print(f"ceiling: solving the Bayes planner ({obj}, {len(rates)} users"
          f"{', leave-one-out' if args.loo_bayes else ''})", file=sys.stderr)
    return ceiling.evaluation_ceiling(rows, rates, train, clusters, obj, turns, args.loo_bayes, priors,
                                      _sessions(args), getattr(args, "questplus_fitted", False))


def _ci(v, digits: int = 2) -> str:
    return "" if not v else f"[{v[0]:.{digits}f}, {v[1]:.{digits}f}]"


def _share(s: dict) -> str:
    """A share only when its gap's interval excludes 0 (``experiments.ceiling.share_of_gap``)."""
    if not s or s.get("share") is None:
        return "-"
    ci = s.get("share_ci")
    return f"{100 * s['share']:.0f} % " + (_ci([100 * x for x in ci], 0) if ci else "[unbounded]")


def _levels(mean, sd) -> str:
    return " ".join(f"{m:.2f}±{v:.2f}" for m, v in zip(mean, sd))


def _d(s: dict, key: str, digits: int) -> str:
    return "" if s.get(key) is None else f"{s[key]:+.{digits}f} {_ci(s.get(key + '_ci'), digits)}"


def format_section(section: dict[str, Any] | None) -> str:
    if not section:
        return ""
    if "note" in section:
        return section["note"]
    digits = 2 if section["objective"] == "score" else 3
    first = section["summary"][0] if section["summary"] else {}
    lines = [f"against the Bayes ceiling, objective {section['objective']} (per {section['turns']}-turn session; "
             f"{first.get('users', '?')} sessions of {first.get('people', '?')} people; mean over people [95 % CI]; "
             "d = policy - reference, paired over people; the ceiling is solved on these users, so its "
             "intervals are conditional on them; a share of a gap only when the gap's interval excludes 0, "
             "with Fieller's interval):",
             f"  {'policy':<22} {'A':>3} {'value':>24} {'d level 2':>24} {'d best fixed (train)':>24} "
             f"{'d ceiling (cond.)':>24} {'d bayes-loo':>24} {'share achievable':>18} {'share oracle':>16}"]
    for s in section["summary"]:
        a = "" if s["assessment"] is None else str(s["assessment"])
        value = f"{s['value']:.{digits}f} {_ci(s['value_ci'], digits)}"
        lines.append(f"  {s['policy']:<22} {a:>3} {value:>24} {_d(s, 'd_level2', digits):>24} "
                     f"{_d(s, 'd_reference', digits):>24} {_d(s, 'd_ceiling', digits):>24} "
                     f"{_d(s, 'd_bayes_loo', digits):>24} {_share(s['achievable_share']):>18} "
                     f"{_share(s['oracle_share']):>16}")
    for c in section.get("prior_checks", []):
        pv = ("" if "predicted_value" not in c else
              f"; expects {c['predicted_value']:.{digits}f}, achieves {c['achieved_value']:.{digits}f}")
        lines.append(f"  prior check {c['prior']:<30} success by level predicted {_levels(c['prior_mean'], c['prior_sd'])}"
                     f" vs users {_levels(c['users_mean'], c['users_sd'])}{pv}")
    nc = section.get("noise_corrected_oracle")
    if nc:
        own, pop = nc["own_rates"], nc["population"]
        lines.append(f"  oracle gap over the best fixed level (by person, {nc['people']} people): own rates "
                     f"{own['oracle_gap']:.{digits}f} {_ci(own['oracle_gap_ci'], digits)}, noise-corrected (true rates "
                     f"spread as the beta-binomial fit supports, between-person SD by level "
                     f"{' '.join(f'{x:.2f}' for x in nc['between_sd'])}) {pop['oracle_gap']:.{digits}f}"
                     + ("" if nc["noise_share"] is None else f"; {100 * nc['noise_share']:.0f} % of the own-rates "
                        "gap is the noise of a few turns per level"))
    if section.get("multi_session_note"):
        lines.append("  " + section["multi_session_note"])
    for m in section.get("multi_session", []):
        if m["policy"] == "pooled-fixed":
            lines.append(f"  {m['sessions']} session(s) of the same participant (value per session; d = - pooled "
                         "fixed level, over people):")
        share = "" if m["oracle_share"] is None else f"{100 * m['oracle_share']:.0f} % of the oracle gap " + (
            _ci([100 * x for x in m["oracle_share_ci"]], 0) if m.get("oracle_share_ci") else "[unbounded]")
        lines.append(f"    {m['policy']:<20} {m['value_per_session']:8.{digits}f} {_ci(m['value_ci'], digits):>18} "
                     f"d {m['d_best_fixed']:+.{digits}f} {_ci(m['d_best_fixed_ci'], digits)} {share}")
    return "\n".join(lines)


def run_user_models(args) -> int:
    """``evaluate --user-models``: experiments.user_models on the held-out sessions."""
    from pathlib import Path

    from nao_trainer.experiments import user_models
    from nao_trainer.learn import artifacts

    source = args.data if args.users == "sessions" or args.data is not None else Path(args.users)
    if source is None or not Path(source).exists():
        raise ConfigError("--user-models needs the dataset: add --data DATASET_ROOT")
    obj = _objective(args)
    rate = obj.rate if obj.is_target else 0.75
    manifest = artifacts.load_manifest(args.models)
    print(f"evaluate --user-models: held-out sessions of {source}", file=sys.stderr)
    summary = user_models.run(Path(source), manifest.get("compat"), int(manifest.get("k", 3)), seed=args.seed,
                              workers=args.workers, rate=rate)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "user_models.json", summary)
    print(user_models.format_summary(summary))
    print(f"  {out / 'user_models.json'}")
    return 0
