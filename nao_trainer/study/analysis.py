"""``study analyse``: the analysis the protocol declared, run on the sessions the study recorded.

Per session (completed, of every participant whose data is kept) the outcomes are the total score
(equation (1) over the valid turns), the mean listening-phase engagement (recomputed from the raw
EEG, ``data.study``), the success rate and the span (the sequence length succeeded at the study's
target rate, 75 % for a score study, under the shipped pooled psychometric prior: a per-session
measure of working memory, ``data.study``). The success rate is set by the policy (the difficulty
it chooses), so it is a manipulation check and never the primary outcome (``study.protocol``).

The pre-registered model is ``y_ij = b0 + sum_a b_a [arm_i = a] + b_s session_ij + u_i + e_ij``
with a random intercept per participant, fitted by REML (statsmodels ``MixedLM``) for the session
effect; the arm contrasts are then tested with each arm's own variance (``analysis.variance: arm``,
the default: participants in different arms vary differently, e.g. a random-difficulty arm more
than a fixed level): per participant the mean of ``y - b_s session``, and for each arm against the
reference arm Welch's t with Satterthwaite's degrees of freedom (with every participant playing
the same sessions this estimate is MixedLM's; its variance is not pooled over arms, and the t
reference, not the normal, is used at small N). ``analysis.variance: pooled`` keeps MixedLM's
Wald estimates with a t reference on N - arms df.

``analysis.baseline_covariate``: session 1 is a baseline; the outcome is the participant's mean
over the later sessions, adjusted for their session-1 value (ANCOVA by OLS, HC2 robust standard
errors, t reference).

Multiplicity (pre-specified): the primary outcome's primary contrast (``analysis.primary_contrast``
against ``analysis.reference_arm``) is tested at alpha; every other pre-registered test (the other
contrasts, the secondary outcomes) gets a Holm-adjusted p-value (``p_holm``).

Intention to treat (``analysis.missing: observed-sessions``): every randomised participant is
analysed in the arm allocated; sessions not completed are missing at random given the arm and the
participant's other sessions; the report counts randomised and analysed participants per arm (a
participant with no completed session has no outcome and is listed as missing). Whatever the
protocol did not declare (an arm x session interaction, descriptive means) is "exploratory".
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nao_trainer.core import distributions
from nao_trainer.data.study import study_session
from nao_trainer.errors import DataError
from nao_trainer.files import write_text_atomic
from nao_trainer.learn.psychometric_prior import load_prior
from nao_trainer.study.registry import Study
from nao_trainer.study.runner import DONE
from nao_trainer.study.power import welch

COLUMNS = ("role", "outcome", "model", "term", "estimate", "se", "df", "ci_low", "ci_high", "p", "p_holm", "n_sessions",
           "n_participants")


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
    itt: dict[str, dict[str, int]] = field(default_factory=dict)  # per arm: randomised, analysed, missing


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
              interaction: bool = False, variance: str = "arm") -> tuple[list[dict[str, Any]], list[str]]:
    """Fixed effects of ``outcome ~ arm [+ session] [+ arm:session] + (1|participant)`` with 95 %
    intervals: the arms tested with their own variances (module docstring) unless ``variance`` is
    ``pooled`` or ``interaction`` (the exploratory model: MixedLM's Wald terms, t reference)."""
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
    n_part = int(frame["participant"].nunique())
    df_pooled = max(n_part - int(frame["arm"].nunique()), 1)
    rows = []
    for term in fit.fe_params.index:
        est, se = float(fit.fe_params[term]), float(fit.bse[term])
        rows.append(_row(_term_name(term), est, se, df_pooled, len(frame), n_part))
    if variance == "arm" and not interaction:
        b_s = float(fit.fe_params.get("session", 0.0))
        rows = [r for r in rows if not r["term"].startswith("arm[")]
        rows += welch_rows(frame, outcome, reference, b_s)
    return rows, notes


def _row(term: str, est: float, se: float, df: float, n_sessions: int, n_part: int) -> dict[str, Any]:
    half = float(distributions.t_ppf(0.975, df)) * se
    p = float(2 * distributions.t_sf(abs(est) / se, df)) if se > 0 else (0.0 if est != 0 else 1.0)
    return {"term": term, "estimate": est, "se": se, "df": float(df), "ci_low": est - half, "ci_high": est + half,
            "p": p, "n_sessions": n_sessions, "n_participants": n_part}


def welch_rows(frame: Any, outcome: str, reference: str, b_session: float) -> list[dict[str, Any]]:
    """Each arm against ``reference`` on the participants' session-adjusted means, each arm with its
    own variance, t with Satterthwaite's df (``study.power.welch``, the power simulation's test)."""
    import numpy as np

    adj = frame[outcome] - b_session * frame["session"]
    means = adj.groupby(frame["participant"]).mean()
    arm_of = frame.groupby("participant")["arm"].first()
    ref = means[arm_of == reference].to_numpy()
    out = []
    for arm in sorted(set(arm_of) - {reference}):
        mine = means[arm_of == arm].to_numpy()
        if len(mine) < 2 or len(ref) < 2:
            continue
        diff, se, df, _ = welch(np.array(mine.mean()), np.array(mine.var(ddof=1)), np.array(float(len(mine))),
                                np.array(ref.mean()), np.array(ref.var(ddof=1)), np.array(float(len(ref))))
        # counts: the model's (every session estimates the session effect), as for MixedLM's terms
        out.append(_row(f"arm[{arm}]", float(diff), float(se), float(df), int(len(frame)), int(len(means))))
    return out


def fit_baseline(data: list[dict[str, Any]], outcome: str, reference: str) -> tuple[list[dict[str, Any]], list[str]]:
    """ANCOVA: the participant's mean ``outcome`` over sessions 2.. on arm + their session-1 value,
    OLS with HC2 robust standard errors (arm-specific variances allowed), t reference."""
    import pandas as pd
    import statsmodels.formula.api as smf

    frame = pd.DataFrame(data).dropna(subset=[outcome])
    base = frame[frame["session"] == 1].groupby("participant")[outcome].mean().rename("baseline")
    later = frame[frame["session"] > 1].groupby("participant").agg(y=(outcome, "mean"), arm=("arm", "first"))
    table = later.join(base, how="inner")
    if len(table) < 4 or table["arm"].nunique() < 2:
        return [], [f"{outcome}: too few participants with a baseline and a later session; baseline model not fitted"]
    fit = smf.ols(f"y ~ C(arm, Treatment(reference={reference!r})) + baseline", table).fit(cov_type="HC2")
    df = max(len(table) - len(fit.params), 1)
    return [_row(_term_name(t), float(fit.params[t]), float(fit.bse[t]), df, int(len(frame)), int(len(table)))
            for t in fit.params.index], []


def holm(pvalues: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values (same order as given)."""
    order = sorted(range(len(pvalues)), key=lambda i: pvalues[i])
    out, running = [0.0] * len(pvalues), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(pvalues) - rank) * pvalues[i]))
        out[i] = running
    return out


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
    an = protocol.analysis
    report = Report(protocol.sha256, an.model, an.reference_arm, data)
    for role, outcomes in (("primary", (protocol.primary,)), ("secondary", protocol.secondary)):
        for outcome in outcomes:
            if an.baseline_covariate:
                rows, notes = fit_baseline(data, outcome, report.reference)
                model = "pre-registered (baseline covariate)"
            else:
                rows, notes = fit_mixed(data, outcome, an.terms, report.reference, variance=an.variance)
                model = "pre-registered"
            report.notes += notes
            if rows:
                report.outcomes.append(outcome)
            report.rows += [{"role": role, "outcome": outcome, "model": model, **r} for r in rows]
            rows, notes = fit_mixed(data, outcome, ("session",), report.reference, interaction=True)
            report.rows += [{"role": "exploratory", "outcome": outcome, "model": "arm x session", **r}
                            for r in rows if ":session" in r["term"]]
    _adjust(report, protocol)
    report.itt = itt_counts(study, data)
    report.text = _text(study, report)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "estimates.csv", _csv(report.rows, COLUMNS))
        write_text_atomic(out / "sessions.csv", _csv(data, tuple(data[0])))
        write_text_atomic(out / "report.txt", report.text + "\n")
    except OSError as exc:
        raise DataError(f"{out}: cannot write the analysis ({exc.strerror}); give another --out") from None
    return report


def _adjust(report: Report, protocol: Any) -> None:
    """The multiplicity plan: the primary contrast at alpha, Holm over every other pre-registered arm test."""
    primary_term = f"arm[{protocol.analysis.primary_contrast}]"
    tests = [r for r in report.rows if r["role"] in ("primary", "secondary") and r["term"].startswith("arm[")]
    rest = [r for r in tests if not (r["role"] == "primary" and r["term"] == primary_term)]
    for r, p in zip(rest, holm([r["p"] for r in rest])):
        r["p_holm"] = p
    for r in tests:
        if r not in rest:
            r["p_holm"] = r["p"]  # the one primary test: not adjusted
            r["primary_test"] = True


def itt_counts(study: Study, data: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per arm: participants randomised, analysed (at least one completed session), missing, withdrawn."""
    analysed = {d["participant"] for d in data}
    out: dict[str, dict[str, int]] = {}
    for p in study.participants:
        c = out.setdefault(p["arm"], {"randomised": 0, "analysed": 0, "missing": 0, "withdrawn": 0})
        c["randomised"] += 1
        c["analysed" if p["pseudonym"] in analysed else "missing"] += 1
        c["withdrawn"] += 1 if p["withdrawn"] else 0
    return out


def _csv(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "" if math.isnan(v) else repr(round(v, 6))
        return str(v)
    return "\n".join([",".join(columns)] + [",".join(cell(r.get(c, "")) for c in columns) for r in rows]) + "\n"


def _text(study: Study, report: Report) -> str:
    protocol = study.protocol
    an = protocol.analysis
    how = ("ANCOVA on the later sessions' mean with session 1 as covariate, OLS, HC2 robust SE, t reference"
           if an.baseline_covariate else
           "linear mixed model, REML, statsmodels MixedLM for the session effect; arm contrasts with each arm's "
           "own variance, Welch t with Satterthwaite df" if an.variance == "arm" else
           "linear mixed model, REML, statsmodels MixedLM, one pooled residual variance, t reference on N - arms df")
    lines = [f"study {protocol.name}: pre-registered analysis",
             f"protocol sha256 {report.protocol_sha256} ({len(study.registry['amendments'])} amendment(s))",
             f"model: {report.model} ({how}; arms against {report.reference}; 95 % intervals)",
             f"primary test: {protocol.primary}, {an.primary_contrast} vs {report.reference} at alpha {an.alpha:g}; "
             "every other test Holm-adjusted (p_holm)",
             f"intention to treat ({an.missing}): every randomised participant in the arm allocated; "
             "sessions not completed missing at random",
             "  " + "; ".join(f"{arm}: {c['randomised']} randomised, {c['analysed']} analysed, {c['missing']} with "
                              f"no completed session, {c['withdrawn']} withdrawn" for arm, c in report.itt.items()),
             f"sessions analysed: {len(report.data)} from {len({d['participant'] for d in report.data})} participants", ""]
    for role in ("primary", "secondary", "exploratory"):
        rows = [r for r in report.rows if r["role"] == role]
        if not rows:
            continue
        lines.append(f"{role.upper()}" + (" (not pre-registered; read as hypotheses)" if role == "exploratory" else ""))
        lines.append(f"  {'outcome':<13} {'term':<24} {'estimate':>9} {'95% CI':>22} {'df':>6} {'p':>7} {'p Holm':>7}")
        for r in rows:
            ci = f"[{r['ci_low']:.3f}, {r['ci_high']:.3f}]"
            ph = "" if "p_holm" not in r else ("primary" if r.get("primary_test") else f"{r['p_holm']:.3f}")
            lines.append(f"  {r['outcome']:<13} {r['term']:<24} {r['estimate']:9.3f} {ci:>22} {r['df']:6.1f} "
                         f"{r['p']:7.3f} {ph:>7}")
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
