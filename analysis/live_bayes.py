"""The live ``bayes`` policy with the psychometric prior against the evaluation's ``bayes-psychometric`` row.

    PYTHONPATH=. python analysis/live_bayes.py [--data DATASET_ROOT] RESULTS_DIR [RESULTS_DIR ...]

RESULTS_DIR: a folder written by ``evaluate --personalise ... --objective OBJ`` (docs/results/ceiling-*),
whose ``personalise.json`` holds the ceiling rows. The live policy is built exactly as ``run --policy bayes
--prior psychometric`` builds it (``policies.bayes.load_bayes``: the shipped prior, fitted on all 50
sessions), its plan is valued exactly on every held-out user's rates (read back from the fixed-level rows)
and summarised beside the stored rows (``experiments.ceiling.achievable``). The evaluation's
``bayes-psychometric`` used the prior fitted on the *other* 49 sessions; with ``--data`` this also says for
how many held-out sessions that leave-one-out fit equals the shipped one (then their plans are the same).
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from nao_trainer.core import bayes, evaluation, objective, psychometric
from nao_trainer.experiments import ceiling
from nao_trainer.learn.psychometric_prior import load_prior
from nao_trainer.policies.bayes import load_bayes

LIVE = "bayes (live, psychometric prior)"


def user_rates(rows: list[dict]) -> dict[str, np.ndarray]:
    """Each user's success per level from the level rows of the ceiling section (fixed:L and the chosen levels)."""
    out: dict[str, dict[int, float]] = {}
    for r in rows:
        lv = int(r["policy"].split(":")[1]) if r["policy"].startswith("fixed:") else r.get("level")
        if lv:
            out.setdefault(r["user"], {})[int(lv)] = float(r["success"])
    missing = [u for u, d in out.items() if len(d) < 4]
    if missing:
        raise SystemExit(f"{missing[0]}: the rows do not give its success at every level")
    return {u: np.array([d[lv] for lv in (1, 2, 3, 4)]) for u, d in out.items()}


def compare(folder: Path, cache: Path) -> None:
    section = json.loads((folder / "personalise.json").read_text())["ceiling"]
    obj, turns, rows = objective.parse(section["objective"]), int(section["turns"]), section["rows"]
    rates = user_rates(rows)
    live = load_bayes(None, "evaluation", turns, str(obj), False, "psychometric", cache=cache)
    names = list(rates)
    value = bayes.evaluate_plan(live.plan, np.array([rates[n] for n in names]))
    clusters = {r["user"]: r.get("cluster", "") for r in rows}
    mine = [ceiling.plan_row(n, clusters[n], LIVE, rates[n], None, value, i, turns, obj,
                             evaluation.optimal(ceiling._table(rates[n]), turns).value) for i, n in enumerate(names)]
    summary = {s["policy"]: s for s in ceiling.achievable(rows + mine)}
    digits = 2 if obj.kind == "score" else 3
    print(f"{folder} ({obj}, {len(names)} users, {turns} turns; first decision of the live policy: level {live.decide()})")
    for pol in (LIVE, "bayes-psychometric", "bayes", "pooled-fixed", "ceiling"):
        s = summary[pol]
        share = s["achievable_share_pooled"]
        ci = share.get("share_ci")
        sh = "" if share["share"] is None else (f"; {100 * share['share']:.0f} % "
                                                + (f"[{100 * ci[0]:.0f}, {100 * ci[1]:.0f}]" if ci else "[unbounded]")
                                                + " of the ceiling's gain over the pooled best level")
        print(f"  {pol:<34} {s['value']:.{digits}f} [{s['value_ci'][0]:.{digits}f}, {s['value_ci'][1]:.{digits}f}]"
              f"  minus ceiling {s['d_ceiling']:+.{digits}f}{sh}")
    stored = {r["user"]: float(r["utility"]) for r in rows if r["policy"] == "bayes-psychometric"}
    diff = np.array([float(value.session[i]) - stored[n] for i, n in enumerate(names)])
    print(f"  live minus bayes-psychometric per user: {int(np.sum(np.abs(diff) > 1e-6))} of {len(names)} differ, "
          f"max |difference| {np.abs(diff).max():.2e}, mean {diff.mean():+.2e}")


def loo_fits(root: str) -> None:
    from nao_trainer.data.dataset import import_dataset
    from nao_trainer.learn.fitting import Turns

    turns = Turns.from_columns(import_dataset(root, compat="authors2018").table.columns)
    shipped = load_prior()
    names = sorted(np.unique(turns.session).tolist())
    same = []
    for s in names:
        rest = turns.session != s
        fit = psychometric.fit(psychometric.session_counts(turns.session[rest], turns.level[rest], turns.success[rest]))
        same.append(all(abs(getattr(fit, k) - getattr(shipped, k)) < 1e-6 for k in ("mu", "tau", "sigma", "lapse")))
        if not same[-1]:
            print(f"  leave-one-out fit without {s}: {fit} (shipped: {shipped})")
    print(f"leave-one-out psychometric fits equal to the shipped one (all 50 sessions): {sum(same)} of {len(same)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--data", help="the published dataset root: also compare the leave-one-out fits")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for folder in args.folders:
            compare(folder, Path(tmp))
    if args.data:
        loo_fits(args.data)


if __name__ == "__main__":
    main()
