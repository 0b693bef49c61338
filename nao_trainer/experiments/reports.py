"""What the experiments write and print: the reports (JSON), tables (CSV and text) and row files of
``nao-trainer evaluate``, ``evaluate --personalise`` and ``sweep``.

Row files are gzip CSV with mtime 0, so the same run gives the same bytes.
"""
from __future__ import annotations

import csv
import gzip
import json
import os
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nao_trainer.experiments import comparison, personalisation
from nao_trainer.experiments.sweep import SweepSpec
from nao_trainer.files import write_json_atomic, write_text_atomic

ROWS_FILE = "evaluation_rows.csv.gz"
PERSONALISE_ROWS_FILE = "personalise_rows.csv.gz"
PERSONALISE_ROW_COLUMNS = ("user", "cluster", "user_best_level", "policy", "assessment", "score", "engagement",
                           "success", "regret", "samples", "switches", "matched", "level", "visits_1", "visits_2",
                           "visits_3", "visits_4")
ENGAGEMENT_ROWS_FILE = "engagement_rows.csv"
ENGAGEMENT_ROW_COLUMNS = ("user", "turns", "outcomes_correct", "outcomes_p_true", "engagement_correct",
                          "engagement_p_true")
ROW_COLUMNS = ("user", "cluster", "policy", "seed", "score", "engagement", "success", "regret", "samples",
               "visits_l1", "visits_l2", "visits_l3", "visits_l4")


# ----------------------------------------------------------------------------------------------
# evaluate: the policy comparison
# ----------------------------------------------------------------------------------------------


def write_comparison(out: Path, rows: list[dict], spec: comparison.EvalSpec, *, command: str, users: str,
                     n_users: int, policy_files: Path | None, started: float,
                     extra: dict[str, Any] | None = None, by_person: bool = False) -> tuple[dict[str, Any], list[Path]]:
    """``evaluation.json``, ``evaluation.csv`` and the row file in ``out``; the report and the paths.
    ``started``: ``time.perf_counter()`` when the run began (the report's ``seconds``); ``extra``: more
    sections of the report (e.g. the Bayes ceiling); ``by_person``: the users are sessions of people,
    so means and intervals are over people (``comparison.summarise``)."""
    summary = comparison.summarise(rows, by_person=by_person)
    report = {
        "command": command, "users": users, "n_users": n_users, "mdp": spec.process,
        "spec": {"policies": list(spec.policies), "seeds": spec.seeds, "episodes": spec.episodes,
                 "mc_episodes": spec.mc_episodes, "turns": spec.turns, "seed": spec.seed,
                 "hyperparameters": spec.config.to_dict(),
                 "policy_files": None if policy_files is None else str(policy_files)},
        "summary": summary, "claims": comparison.claims(rows, by_person), "rows_file": ROWS_FILE,
        **(extra or {}), "seconds": round(time.perf_counter() - started, 2),
    }
    out = Path(out)
    write_json_atomic(out / "evaluation.json", report)
    write_text_atomic(out / "evaluation.csv", to_csv(summary))
    write_rows(rows, out / ROWS_FILE)
    return report, [out / "evaluation.json", out / "evaluation.csv", out / ROWS_FILE]


def _ci(v, digits=2) -> str:
    return "n/a" if v is None else f"[{v[0]:.{digits}f}, {v[1]:.{digits}f}]"


def _lo_hi(ci) -> tuple[str, str]:
    return ("", "") if not ci else (f"{ci[0]:.6g}", f"{ci[1]:.6g}")


def _unit_header(summary: list[dict]) -> str:
    if summary and summary[0].get("unit") == "people":
        return (f"means and 95 % t-intervals over {summary[0]['people']} people ({summary[0]['users']} sessions; "
                "a person's sessions and seeds averaged); n = people")
    return "means and 95 % t-intervals over (user, seed) rows; n = rows"


def format_table(summary: list[dict], claims: list[dict]) -> str:
    """The summary as aligned text; d best-fixed = paired score difference to the best fixed level."""
    lines = [_unit_header(summary), f"{'policy':<26} {'n':>4} {'score':>7} {'95% CI':>17} {'engage':>7} {'success':>7} "
             f"{'regret':>7} {'95% CI':>17} {'d best-fixed':>13} {'95% CI':>17}"]
    for s in summary:
        ref = s.get("vs_reference")
        d = "" if ref is None else f"{ref['score_diff']:+.2f}"
        dci = "" if ref is None else _ci(ref["score_diff_ci"])
        lines.append(f"{s['policy']:<26} {s['n']:>4} {s['score']:7.2f} {_ci(s['score_ci']):>17} {s['engagement']:7.3f} "
                     f"{s['success']:7.3f} {s['regret']:7.2f} {_ci(s['regret_ci']):>17} {d:>13} {dci:>17}")
    if claims:
        over = "people" if claims[0].get("unit") == "people" else "users x seeds"
        lines.append(f"engagement feedback vs the performance-only learner (paired over {over}):")
        for c in claims:
            lines.append(f"  {c['a']:<22} - {c['b']:<26} score {c['score_diff']:+.2f} {_ci(c['score_diff_ci'])}  "
                         f"engagement {c['engagement_diff']:+.4f} {_ci(c['engagement_diff_ci'], 4)}")
    return "\n".join(lines)


def per_user_table(rows: list[dict]) -> str:
    """Mean score over seeds of every (user, policy): one line per policy, one column per user."""
    user_names = list(dict.fromkeys(r["user"] for r in rows))
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    lines = ["score per user (mean over seeds): " + ", ".join(user_names)]
    for pol in policies:
        vals = [np.mean([r["score"] for r in rows if r["user"] == u and r["policy"] == pol]) for u in user_names]
        lines.append(f"  {pol:<26} " + " ".join(f"{v:7.2f}" for v in vals))
    return "\n".join(lines)


def _write_gzip_lines(lines: Sequence[str], path: Path) -> None:
    """``lines`` as a gzip text file, written beside and renamed over ``path`` (mtime 0)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0, filename="") as fh:
        fh.write(("\n".join(lines) + "\n").encode())
    os.replace(tmp, path)


def write_rows(rows: list[dict], path: Path) -> None:
    """Every (user, policy, seed) row as gzip CSV."""
    lines = [",".join(ROW_COLUMNS)]
    for r in rows:
        vals = [r["user"], r["cluster"], r["policy"], "" if r["seed"] is None else r["seed"], repr(r["score"]),
                repr(r["engagement"]), repr(r["success"]), repr(r["regret"]), r["samples"], *r["visits"]]
        lines.append(",".join(str(v) for v in vals))
    _write_gzip_lines(lines, path)


def read_rows(path: Path) -> list[dict]:
    """Rows written by ``write_rows`` (numbers as floats, seed None for baselines)."""
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
        vals = [s["policy"], s["n"], s["users"], f"{s['score']:.6g}", *_lo_hi(s["score_ci"]), f"{s['engagement']:.6g}",
                *_lo_hi(s["engagement_ci"]), f"{s['success']:.6g}", f"{s['regret']:.6g}", *_lo_hi(s["regret_ci"]),
                "" if not ref else f"{ref['score_diff']:.6g}", *_lo_hi(ref.get("score_diff_ci"))]
        lines.append(",".join(str(v) for v in vals))
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# evaluate --personalise
# ----------------------------------------------------------------------------------------------


def write_personalisation(out: Path, result: dict[str, Any], spec: personalisation.PersonaliseSpec, *,
                          command: str, started: float,
                          export_users: Path | None = None,
                          extra: dict[str, Any] | None = None) -> tuple[dict[str, Any], list[Path]]:
    """``personalise.json``, ``personalise.csv``, the row file (and each user's simulator in
    ``export_users``); the report and the paths."""
    summary = personalisation.summarise(result["rows"])
    engagement = personalisation.summarise_engagement(result["engagement"])
    # the per-session measurements are in ENGAGEMENT_ROWS_FILE: re-summarise with read_engagement_rows
    report = {"command": command,
              "users": "sessions (leave-one-person-out)", "n_users": len(result["users"]),
              "spec": {"lengths": list(spec.lengths), "levels": list(spec.levels), "kappa": spec.kappa,
                       "session_prior": "data" if spec.session_prior is None else spec.session_prior,
                       "margin": spec.margin, "method": spec.method, "episodes": spec.episodes,
                       "mc_episodes": spec.mc_episodes, "turns": spec.turns, "seed": spec.seed},
              "summary": summary, "engagement_information": engagement,
              "engagement_rows_file": ENGAGEMENT_ROWS_FILE, "rows_file": PERSONALISE_ROWS_FILE,
              **(extra or {}), "seconds": round(time.perf_counter() - started, 2)}
    out = Path(out)
    write_json_atomic(out / "personalise.json", report)
    write_text_atomic(out / "personalise.csv", personalise_csv(summary))
    write_personalise_rows(result["rows"], out / PERSONALISE_ROWS_FILE)
    write_engagement_rows(result["engagement"], out / ENGAGEMENT_ROWS_FILE)
    paths = [out / "personalise.json", out / "personalise.csv", out / PERSONALISE_ROWS_FILE,
             out / ENGAGEMENT_ROWS_FILE]
    if export_users is not None:
        for user in result["users"]:
            name = user["name"].removeprefix("session:").replace("/", "_")
            write_json_atomic(Path(export_users) / f"{name}.json", user)
        paths.append(Path(export_users))
    return report, paths


def _share(g: dict) -> str:
    if g.get("share") is None:
        return "n/a"
    return f"{g['share']:+.2f} {_ci(g['share_ci'])}"


def format_personalise(summary: list[dict], engagement: list[dict]) -> str:
    """The personalisation summary as aligned text (d best-fixed: paired score difference)."""
    lines = [(f"means and 95 % t-intervals over {summary[0]['people']} people ({summary[0]['users']} held-out sessions; "
              "a person's sessions averaged); gap closed: bootstrap over people") if summary and "people" in summary[0]
             else "means and 95 % t-intervals over held-out sessions",
             f"{'policy':<14} {'A':>3} {'score':>7} {'95% CI':>17} {'d best-fixed':>13} {'95% CI':>17} "
             f"{'gap closed':>24} {'matched':>8}"]
    for s in summary:
        a = "" if s["assessment"] is None else str(s["assessment"])
        d = "" if s["d_reference"] is None else f"{s['d_reference']:+.2f}"
        m = f"{s['matched']:.2f}" if "matched" in s else ""
        lines.append(f"{s['policy']:<14} {a:>3} {s['score']:7.2f} {_ci(s['score_ci']):>17} {d:>13} "
                     f"{_ci(s['d_reference_ci']):>17} {_share(s['gap_closed']):>24} {m:>8}")
    if engagement:
        lines.append(format_engagement(engagement))
    return "\n".join(lines)


def format_engagement(engagement: list[dict]) -> str:
    """"Does engagement help the match?" as text: means over people, the difference's 95 % t-interval."""
    first = engagement[0]
    unit = (f"{first['people']} people ({first['sessions']} held-out sessions; a person's sessions averaged)"
            if "people" in first else f"{first['sessions']} held-out sessions")
    lines = [f"does engagement help the match? (real turns of each held-out session; P = P(its cluster); "
             f"means and 95 % t-interval over {unit})"]
    for e in engagement:
        a, b = e["outcomes"], e["outcomes+engagement"]
        lines.append(f"  first {e['turns']:2d} turns: outcomes only {a['accuracy']:.2f} right, P {a['p_true']:.2f}; "
                     f"with engagement {b['accuracy']:.2f} right, P {b['p_true']:.2f}; "
                     f"diff P {e['p_true_diff']:+.3f} {_ci(e['p_true_diff_ci'], 3)}")
    return "\n".join(lines)


def personalise_csv(summary: list[dict]) -> str:
    cols = ["policy", "assessment", "users", "people", "score", "score_lo", "score_hi", "d_best_fixed", "d_best_fixed_lo",
            "d_best_fixed_hi", "gap_closed", "gap_closed_lo", "gap_closed_hi", "regret", "matched", "switches"]
    lines = [",".join(cols)]
    for s in summary:
        g = s["gap_closed"]
        vals = [s["policy"], "" if s["assessment"] is None else s["assessment"], s["users"], s.get("people", ""),
                f"{s['score']:.6g}",
                *_lo_hi(s["score_ci"]), "" if s["d_reference"] is None else f"{s['d_reference']:.6g}",
                *_lo_hi(s["d_reference_ci"]), "" if g.get("share") is None else f"{g['share']:.6g}",
                *_lo_hi(g.get("share_ci")), f"{s['regret']:.6g}", s.get("matched", ""), s.get("switches", "")]
        lines.append(",".join(str(v) for v in vals))
    return "\n".join(lines) + "\n"


def write_personalise_rows(rows: list[dict], path: Path) -> None:
    """Every (user, policy, assessment length) row of ``--personalise`` as gzip CSV."""
    lines = [",".join(PERSONALISE_ROW_COLUMNS)]
    for r in rows:
        vals = [r.get(k) for k in PERSONALISE_ROW_COLUMNS[:-4]] + list(r["visits"])
        lines.append(",".join("" if v is None else repr(v) if isinstance(v, float) else str(v) for v in vals))
    _write_gzip_lines(lines, path)


_ENGAGEMENT_LABELS = (("outcomes", "outcomes"), ("engagement", "outcomes+engagement"))


def write_engagement_rows(meas: list[dict], path: Path) -> None:
    """The per-session engagement measurements (``personalisation.engagement_information``) as CSV,
    floats as ``repr`` so that ``read_engagement_rows`` gives them back exactly."""
    lines = [",".join(ENGAGEMENT_ROW_COLUMNS)]
    for m in meas:
        vals = [m["user"], str(int(m["turns"]))]
        for _, label in _ENGAGEMENT_LABELS:
            vals += [str(bool(m[label]["correct"])), repr(float(m[label]["p_true"]))]
        lines.append(",".join(vals))
    write_text_atomic(Path(path), "\n".join(lines) + "\n")


def read_engagement_rows(path: Path) -> list[dict]:
    """The measurements ``write_engagement_rows`` wrote (``personalisation.summarise_engagement`` takes them)."""
    with open(path, newline="") as fh:
        return [{"user": r["user"], "turns": int(r["turns"]),
                 **{label: {"correct": r[f"{col}_correct"] == "True", "p_true": float(r[f"{col}_p_true"])}
                    for col, label in _ENGAGEMENT_LABELS}} for r in csv.DictReader(fh)]


def rewrite_engagement(out: Path, meas: list[dict], command: str) -> dict[str, Any]:
    """Replace the engagement part of an ``evaluate --personalise`` output folder (its row file and
    ``personalise.json``'s ``engagement_information``) by ``meas``, keeping everything else of the
    report; ``command`` (what recomputed it) is recorded as ``engagement_command``. The report."""
    out = Path(out)
    report = json.loads((out / "personalise.json").read_text())
    report["engagement_information"] = personalisation.summarise_engagement(meas)
    report["engagement_rows_file"] = ENGAGEMENT_ROWS_FILE
    report["engagement_command"] = command
    write_engagement_rows(meas, out / ENGAGEMENT_ROWS_FILE)
    write_json_atomic(out / "personalise.json", report)
    return report


# ----------------------------------------------------------------------------------------------
# sweep
# ----------------------------------------------------------------------------------------------


def write_sweep(out: Path, results: list[dict], spec: SweepSpec, *, command: str,
                seconds: float) -> tuple[dict[str, Any], list[str], list[Path]]:
    """``sweep.json`` and ``sweep.csv`` in ``out``; the report, the CSV lines (printed) and the paths."""
    report = {"command": command, "method": spec.method,
              "mdp": spec.process, "params": {n: list(v) for n, v in spec.params}, "seeds": spec.seeds,
              "episodes": spec.episodes, "seed": spec.seed, "seconds": round(seconds, 2), "results": results}
    out = Path(out)
    write_json_atomic(out / "sweep.json", report)
    names = [n for n, _ in spec.params]
    lines = [",".join(["user", *names, "method", "score", "score_lo", "score_hi", "engagement", "training_tail_score"])]
    for r in results:
        ci = r["score_ci"] or [r["score"], r["score"]]
        lines.append(",".join([r["user"], *(f"{r[n]:.6g}" for n in names), r["method"], f"{r['score']:.6g}",
                               f"{ci[0]:.6g}", f"{ci[1]:.6g}", f"{r['engagement']:.6g}", f"{r['training_tail_score']:.6g}"]))
    write_text_atomic(out / "sweep.csv", "\n".join(lines) + "\n")
    return report, lines, [out / "sweep.json", out / "sweep.csv"]
