"""``study analyse``: the analysis the protocol declared, run on the sessions the study recorded.

Per session (completed, of every participant whose data is kept; intention to treat: withdrawn
participants' kept sessions count) the outcomes are the total score (equation (1) over the valid turns),
the mean listening-phase engagement (recomputed from the raw EEG, ``data.study``), the success rate and
the span (the sequence length succeeded at the study's target rate, 75 % for a score study, under the
shipped pooled psychometric prior: a per-session measure of working memory, ``data.study``).
The pre-registered model is a linear mixed model with a random intercept per participant,

    y_ij = b0 + sum_a b_a [arm_i = a] + b_s * session_ij + u_i + e_ij,   u_i ~ N(0, s_u^2), e_ij ~ N(0, s_e^2)

fitted by REML (statsmodels ``MixedLM``), the arms coded against the protocol's reference arm; each
estimate comes with its Wald 95 % interval and p-value. Whatever the protocol did not declare (an
arm x session interaction, descriptive means) is written under "exploratory".
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nao_trainer.data.study import study_session
from nao_trainer.errors import DataError
from nao_trainer.files import write_text_atomic
from nao_trainer.learn.psychometric_prior import load_prior
from nao_trainer.study.registry import Study
from nao_trainer.study.runner import DONE

COLUMNS = ("role", "outcome", "model", "term", "estimate", "ci_low", "ci_high", "p", "n_sessions", "n_participants")


@dataclass
class Report:
    protocol_sha256: str
    model: str
    reference: str
    data: list[dict[str, Any]]  # one row per session: participant, arm, session, outcomes
    rows: list[dict[str, Any]] = field(default_factory=list)  # estimates (COLUMNS)
    notes: list[str] = field(default_factory=list)
    outcomes: list[str] = field(default_factory=list)  # outcomes with a fitted model
    text: str = ""


def session_table(study: Study) -> list[dict[str, Any]]:
    """One row per counted session: participant, arm, session number and the outcomes."""
    prior = load_prior()
    out = []
    for p in study.participants:
        if p["withdrawn"] and p["withdrawn"]["data"] == "delete":
            continue
        for s in p["sessions"]:
            if s["status"] not in DONE:
                continue
            folder = study.sessions_dir / s["folder"]
            try:
                sess = study_session(folder, prior)
            except DataError as exc:
                raise DataError(f"{folder}: cannot be analysed ({exc}); restore it or withdraw its data") from None
            row, success = sess.row, sum(sess.success)
            out.append({"participant": p["pseudonym"], "arm": p["arm"], "session": int(s["number"]),
                        "score": float(row["score"]),
                        "engagement": math.nan if row["engagement"] is None else float(row["engagement"]),
                        "success_rate": success / len(sess.success) if sess.success else math.nan,
                        "span": math.nan if row["span"] is None else float(row["span"]),
                        "turns": int(row["turns"])})
    return out


def fit_mixed(data: list[dict[str, Any]], outcome: str, terms: tuple[str, ...], reference: str,
              interaction: bool = False) -> tuple[list[dict[str, Any]], list[str]]:
    """Fixed effects of ``outcome ~ arm [+ session] [+ arm:session] + (1|participant)`` with 95 % CIs."""
    try:
        import pandas as pd
        import statsmodels.formula.api as smf
    except ImportError as exc:
        raise DataError(f"the analysis needs statsmodels and pandas ({exc}); pip install 'nao-trainer[study]'") from None

    frame = pd.DataFrame(data).dropna(subset=[outcome])
    notes: list[str] = []
    if frame["participant"].nunique() < 3 or frame["arm"].nunique() < 2:
        return [], [f"{outcome}: too few participants or arms with data ({len(frame)} sessions); not fitted"]
    rhs = f"C(arm, Treatment(reference={reference!r}))"
    if "session" in terms:
        rhs += " + session"
    if interaction:
        rhs += f" + C(arm, Treatment(reference={reference!r})):session"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            fit = smf.mixedlm(f"{outcome} ~ {rhs}", frame, groups=frame["participant"]).fit(reml=True)
        except (ValueError, ArithmeticError, __import__("numpy").linalg.LinAlgError) as exc:
            return [], [f"{outcome}: the mixed model could not be fitted ({exc})"]
    notes += sorted({f"{outcome}: {type(w.message).__name__}: {w.message}".split("\n")[0] for w in caught
                     if "converge" in str(w.message).lower() or "boundary" in str(w.message).lower()})
    ci = fit.conf_int(0.05)
    rows = []
    for term in fit.fe_params.index:
        rows.append({"term": _term_name(term), "estimate": float(fit.fe_params[term]),
                     "ci_low": float(ci.loc[term, 0]), "ci_high": float(ci.loc[term, 1]),
                     "p": float(fit.pvalues[term]), "n_sessions": len(frame),
                     "n_participants": int(frame["participant"].nunique())})
    return rows, notes


def _term_name(term: str) -> str:
    """``C(arm, Treatment(reference='x'))[T.y]`` -> ``arm[y]``."""
    if term.startswith("C(arm"):
        level = term.split("[T.", 1)[1].split("]", 1)[0]
        return f"arm[{level}]" + (":session" if term.endswith(":session") else "")
    return term


def analyse(study: Study, out: Path) -> Report:
    """Fit the protocol's model per outcome; write ``estimates.csv``, ``sessions.csv`` and ``report.txt``."""
    protocol = study.protocol
    data = session_table(study)
    if not data:
        raise DataError(f"{study.root}: no completed session to analyse yet; run sessions with `study next`")
    report = Report(protocol.sha256, protocol.analysis.model, protocol.analysis.reference_arm, data)
    for role, outcomes in (("primary", (protocol.primary,)), ("secondary", protocol.secondary)):
        for outcome in outcomes:
            rows, notes = fit_mixed(data, outcome, protocol.analysis.terms, report.reference)
            report.notes += notes
            if rows:
                report.outcomes.append(outcome)
            report.rows += [{"role": role, "outcome": outcome, "model": "pre-registered", **r} for r in rows]
            rows, notes = fit_mixed(data, outcome, ("session",), report.reference, interaction=True)
            report.rows += [{"role": "exploratory", "outcome": outcome, "model": "arm x session", **r}
                            for r in rows if ":session" in r["term"]]
    report.text = _text(study, report)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "estimates.csv", _csv(report.rows, COLUMNS))
        write_text_atomic(out / "sessions.csv", _csv(data, tuple(data[0])))
        write_text_atomic(out / "report.txt", report.text + "\n")
    except OSError as exc:
        raise DataError(f"{out}: cannot write the analysis ({exc.strerror}); give another --out") from None
    return report


def _csv(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "" if math.isnan(v) else repr(round(v, 6))
        return str(v)
    return "\n".join([",".join(columns)] + [",".join(cell(r.get(c, "")) for c in columns) for r in rows]) + "\n"


def _text(study: Study, report: Report) -> str:
    protocol = study.protocol
    lines = [f"study {protocol.name}: pre-registered analysis",
             f"protocol sha256 {report.protocol_sha256} ({len(study.registry['amendments'])} amendment(s))",
             f"model: {report.model} (linear mixed model, REML, statsmodels MixedLM; arms against "
             f"{report.reference}; 95 % Wald intervals)",
             f"sessions analysed: {len(report.data)} from {len({d['participant'] for d in report.data})} participants", ""]
    for role in ("primary", "secondary", "exploratory"):
        rows = [r for r in report.rows if r["role"] == role]
        if not rows:
            continue
        lines.append(f"{role.upper()}" + (" (not pre-registered; read as hypotheses)" if role == "exploratory" else ""))
        lines.append(f"  {'outcome':<13} {'term':<24} {'estimate':>9} {'95% CI':>22} {'p':>7}")
        for r in rows:
            ci = f"[{r['ci_low']:.3f}, {r['ci_high']:.3f}]"
            lines.append(f"  {r['outcome']:<13} {r['term']:<24} {r['estimate']:9.3f} {ci:>22} {r['p']:7.3f}")
        lines.append("")
    lines.append("EXPLORATORY: mean per arm and session (descriptive)")
    for arm in protocol.arms:
        for n in sorted({d["session"] for d in report.data}):
            sel = [d for d in report.data if d["arm"] == arm.name and d["session"] == n]
            if sel:
                means = {o: _mean([d[o] for d in sel]) for o in ("score", "engagement", "success_rate", "span")}
                lines.append(f"  {arm.name:<14} session {n}: n={len(sel):<3} score {means['score']:.2f}  engagement "
                             f"{means['engagement']:.3f}  success rate {means['success_rate']:.3f}  span "
                             f"{means['span']:.2f}")
    lines += [f"note: {n}" for n in report.notes]
    return "\n".join(lines)


def _mean(values: list[float]) -> float:
    ok = [v for v in values if not math.isnan(v)]
    return sum(ok) / len(ok) if ok else math.nan
