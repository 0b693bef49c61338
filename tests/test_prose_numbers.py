"""The hand-written numbers of the results pages are the stored outputs' numbers.

The generated blocks of the pages are checked by tests/test_results_page.py; the prose around them
quotes numbers too (headline differences with their intervals, ceiling gaps, power per arm...). Each
case below is (page, the quoted text with its numbers as format fields, where they come from in
docs/results/** or docs/study/**): the text, formatted from the stored output, must be on the page
(whitespace-insensitive). A number that drifts on the page, or an output that changes under a page,
fails here; the fix is to edit the page (or to regenerate the output), never this table's numbers.
Reads files only.
"""
from __future__ import annotations

import csv
import gzip
import json
import math
import re
import string
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "docs" / "results"
SUMMARY, RESULTS_MD, STUDY = ("docs/explanation/results-summary.md", "docs/explanation/results.md",
                              "docs/how-to/study.md")
PERSONALISATION = "docs/explanation/personalisation.md"


# ----------------------------------------------------------------------------------------------
# the stored outputs
# ----------------------------------------------------------------------------------------------


@lru_cache(maxsize=None)
def stored(rel: str) -> Any:
    """A stored JSON output, by its path under the repository."""
    return json.loads((ROOT / rel).read_text())


def evaluation(users: str, policy: str) -> dict:
    return next(s for s in stored(f"docs/results/{users}/evaluation.json")["summary"] if s["policy"] == policy)


def d_best(users: str, policy: str) -> tuple[float, float, float]:
    """(d, lo, hi) of ``evaluate``'s policy − best fixed level."""
    v = evaluation(users, policy)["vs_reference"]
    return (v["score_diff"], *v["score_diff_ci"])


def claim(users: str, a: str, key: str = "score") -> tuple[float, float, float]:
    c = next(c for c in stored(f"docs/results/{users}/evaluation.json")["claims"] if c["a"] == a)
    return (c[f"{key}_diff"], *c[f"{key}_diff_ci"])


EVAL_SETS = ("clusters", "level-only", "clusters-tested", "sessions")


def personalise(folder: str, policy: str, length: int | None = None) -> dict:
    return next(s for s in stored(f"docs/results/{folder}/personalise.json")["summary"]
                if s["policy"] == policy and s["assessment"] == length)


def lengths(folder: str) -> list[int]:
    return sorted({s["assessment"] for s in stored(f"docs/results/{folder}/personalise.json")["summary"]
                   if s["assessment"] is not None})


PERSONALISE = ("personalise", "personalise-own-rates")
PIPELINES = ("paper", "posterior-ev", "personalised")


def engagement(folder: str, turns: int) -> dict:
    return next(e for e in stored(f"docs/results/{folder}/personalise.json")["engagement_information"]
                if e["turns"] == turns)


def power(users: str, key: str) -> dict:
    """A contrast of `study power`'s stored output: its power per N, its effect at the largest N and the N
    for 80 % power as the power table gives it (``PowerReport.n_for_80``: simulated, or extrapolated)."""
    from nao_trainer.study.power import PowerReport

    j = stored(f"docs/study/{users}/power.json")
    arms = {a for k in j["power"] for a in k.split(": ", 1)[1].split(" vs ")}
    rep = PowerReport(arms=len(arms), name=j["protocol"], protocol_sha256=j["protocol_sha256"], ns=j["ns"],
                      reps=j["reps"], alpha=j["alpha"], users=j["users"], drift=j["drift"], power=j["power"],
                      effect=j["effect"], sd=j["sd"], sd_ref=j.get("sd_ref", {}))
    return {"power": dict(zip(j["ns"], j["power"][key])), "effect": j["effect"][key][-1],
            "n80": int(re.sub(r"[^0-9]", "", rep.n_for_80(key)))}


def user_models(model: str) -> dict:
    return next(m for m in stored("docs/results/user-models/user_models.json")["models"] if m["model"] == model)


def variant(i: int) -> dict:
    return stored("docs/results/user_model_variants.json")["variants"][i]


@lru_cache(maxsize=None)
def eval_rows(users: str) -> list[dict]:
    with gzip.open(RESULTS / users / "evaluation_rows.csv.gz", "rt") as fh:
        return list(csv.DictReader(fh))


def by_cluster(users: str, policy: str) -> dict[str, float]:
    """Mean score per cluster (over its users and seeds) of a policy in an ``evaluate`` output's rows."""
    acc: dict[str, list[float]] = {}
    for r in eval_rows(users):
        if r["policy"] == policy:
            acc.setdefault(r["cluster"], []).append(float(r["score"]))
    return {c: sum(v) / len(v) for c, v in acc.items()}


def oracle_by_cluster(users: str) -> dict[str, float]:
    return by_cluster(users, "oracle")


# ----------------------------------------------------------------------------------------------
# the cases
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Quote:
    page: str
    text: str  # the quoted text; {0:.2f}-style fields take values() in order
    values: Callable[[], tuple]
    minus: str = "−"  # how the page writes a minus sign in this text ("-" or "−")

    def expected(self) -> str:
        """The quoted text with its fields formatted from the stored outputs (whitespace collapsed)."""
        vals, out = self.values(), []
        for literal, field, spec, _ in string.Formatter().parse(self.text):
            out.append(literal)
            if field is not None:
                out.append(format(vals[int(field)], spec).replace("-", self.minus))
        return " ".join("".join(out).split())


def spread(values) -> tuple[float, float]:
    v = list(values)
    return min(v), max(v)


def _abs_range(values) -> tuple[float, float]:
    v = [abs(x) for x in values]
    return min(v), max(v)


CASES: list[Quote] = [
    # --- results-summary.md: policies -------------------------------------------------------
    *[Quote(SUMMARY, f"| {label} | {{0:.2f}} | {{1:.2f}} | {{2:.2f}} | {{3:.2f}} | {{4:.2f}} | {{5:.2f}} |",
            lambda u=users: tuple(evaluation(u, p)["score"] for p in ("fixed:2", "best-fixed", "usp:performance",
                                                                      "usp:qaug", "usp:shaping", "oracle")))
      for users, label in (("clusters", "clusters as shipped (authors' fit, with feedback effects)"),
                           ("level-only", "the same clusters, level-only"),
                           ("clusters-tested", "clusters refitted with only tested effects"),
                           ("sessions", "50 real sessions of 48 people, leave the person out"))],
    Quote(SUMMARY, "beat a fixed level only on the authors' fitted simulators (+{0:.1f} points [{1:.1f}, {2:.1f}])",
          lambda: d_best("clusters", "usp:performance")),
    Quote(SUMMARY, "**always level 2 is optimal or within {0:.2f} points of it**",
          lambda: (max(evaluation(u, "oracle")["score"] - evaluation(u, "fixed:2")["score"]
                       for u in ("level-only", "clusters-tested", "sessions")),)),
    Quote(SUMMARY, "(sessions, over people: {0:.2f} [{1:.2f}, {2:.2f}] and {3:.2f} [{4:.2f}, {5:.2f}])",
          lambda: (*d_best("sessions", "usp:performance"), *d_best("sessions", "usp:qaug"))),
    Quote(SUMMARY, "reward shaping lowers the score by up to {0:.1f} points without raising engagement",
          lambda: (max(-claim(u, "usp:shaping")[0] for u in EVAL_SETS),)),
    Quote(SUMMARY, "(+{0:.1f} in the authors' cluster 2)",
          lambda: (oracle_by_cluster("clusters-informed")["2"] - oracle_by_cluster("clusters")["2"],)),
    Quote(SUMMARY, "2-down/1-up staircases score {0:.1f}-{1:.1f} points below the best fixed level everywhere",
          lambda: _abs_range(d_best(u, p)[0] for u in EVAL_SETS
                             for p in ("staircase:1u1d@2", "staircase:2d1u@2"))),
    # --- results-summary.md: personalisation ----------------------------------------------
    *[Quote(SUMMARY, f"| {label} | {{0:.2f}} | {{1:.2f}} | {{2:.2f}} | {{3:.2f}} | {{4:.2f}} | {{5:.2f}} | {{6:.2f}} |",
            lambda f=folder: tuple(personalise(f, p, a)["score"] for p, a in (
                ("fixed:2", None), ("best-fixed", None), ("generic", None), ("paper", 6), ("personalised", 0),
                ("personalised", 6), ("oracle", None))))
      for folder, label in (("personalise", "sessions, data prior (default)"),
                            ("personalise-own-rates", "sessions, own rates (`--session-prior 2`)"))],
    Quote(SUMMARY, "(own rates: the oracle is {0:.1f} points above the best fixed level)",
          lambda: (personalise("personalise-own-rates", "oracle")["d_reference"],)),
    Quote(SUMMARY, "the whole pipeline without an assessment beats the best fixed level by {0:.2f} [{1:.2f}, {2:.2f}] "
                   "and closes {3:.0f} % [{4:.0f} %, {5:.0f} %] of the gap",
          lambda: (personalise("personalise-own-rates", "personalised", 0)["d_reference"],
                   *personalise("personalise-own-rates", "personalised", 0)["d_reference_ci"],
                   *(100 * x for x in [personalise("personalise-own-rates", "personalised", 0)["gap_closed"]["share"],
                                       *personalise("personalise-own-rates", "personalised", 0)["gap_closed"]["share_ci"]]))),
    Quote(SUMMARY, "On the default per-session users there is no room at all ({0:.2f} points)",
          lambda: (personalise("personalise", "oracle")["d_reference"],)),
    Quote(SUMMARY, "assessment loses {0:.1f}-{1:.1f} points",
          lambda: _abs_range(personalise(f, "personalised", 6)["d_reference"] for f in PERSONALISE)),
    Quote(SUMMARY, "choosing by posterior expected value is {0:.1f}-{1:.1f} points better",
          lambda: spread(personalise(f, "posterior-ev", a)["score"] - personalise(f, "paper", a)["score"]
                         for f in PERSONALISE for a in lengths(f))),
    Quote(SUMMARY, "Engagement does not measurably improve the match ({0:+.2f} [{1:.2f}, {2:.2f}] in P(right cluster) "
                   "after 6 turns, over the {3} people)",
          lambda: (engagement("personalise", 6)["p_true_diff"], *engagement("personalise", 6)["p_true_diff_ci"],
                   engagement("personalise", 6)["people"])),
    Quote(SUMMARY, "held-out turns at least as well as the per-level model: {0:+.4f} [{1:+.4f}, {2:+.4f}] nats per turn",
          lambda: (user_models("psychometric")["d_per_level"], *user_models("psychometric")["d_per_level_ci"]),
          minus="−"),
    Quote(SUMMARY, "less well calibrated ({0:.3f} vs {1:.3f})",
          lambda: (user_models("psychometric")["calibration"]["ece"], user_models("per-level")["calibration"]["ece"])),
    # --- results.md: prose around the generated tables ---------------------------------------
    Quote(RESULTS_MD, "fixed level 2 is the optimum or within {0:.2f} points of it",
          lambda: (max(evaluation(u, "oracle")["score"] - evaluation(u, "fixed:2")["score"]
                       for u in ("level-only", "clusters-tested", "sessions")),)),
    Quote(RESULTS_MD, "learners lose {0:.2f} [{2:.2f}, {1:.2f}] and {3:.2f} [{5:.2f}, {4:.2f}] points to the best fixed level",
          lambda: tuple(-x for x in (*d_best("sessions", "usp:performance"), *d_best("sessions", "usp:qaug")))),
    Quote(RESULTS_MD, "reward shaping loses {0:.1f}.", lambda: (-d_best("sessions", "usp:shaping")[0],)),
    Quote(RESULTS_MD, "there they beat the best fixed level by {0:.1f} points [{1:.1f}, {2:.1f}]",
          lambda: d_best("clusters", "usp:performance")),
    Quote(RESULTS_MD, "with them removed (level-only) the edge is gone ({0:+.2f} [{1:.2f}, {2:.2f}])",
          lambda: d_best("level-only", "usp:performance")),
    Quote(RESULTS_MD, "(score differences {0:.2f} to {1:+.2f}, every interval contains 0; engagement differences below {2})",
          lambda: (*spread(claim(u, "usp:qaug")[0] for u in EVAL_SETS),
                   math.ceil(1000 * max(abs(claim(u, "usp:qaug", "engagement")[0]) for u in EVAL_SETS)) / 1000)),
    Quote(RESULTS_MD, "Reward shaping costs {0:.1f} to {1:.1f} points and does not raise engagement "
                      "(differences {2:.3f} to {3:+.3f};",
          lambda: (*_abs_range(claim(u, "usp:shaping")[0] for u in EVAL_SETS),
                   *spread(claim(u, "usp:shaping", "engagement")[0] for u in EVAL_SETS))),
    Quote(RESULTS_MD, "by {0:.1f} points in the authors' cluster 2, {1:.1f} in cluster 1, {2:.0f} in cluster 3",
          lambda: tuple(oracle_by_cluster("clusters-informed")[c] - oracle_by_cluster("clusters")[c]
                        for c in ("2", "1", "3"))),
    Quote(RESULTS_MD, "1-up/1-down and 2-down/1-up score {0:.1f}-{1:.1f} points below the best",
          lambda: _abs_range(d_best(u, p)[0] for u in EVAL_SETS for p in ("staircase:1u1d@2", "staircase:2d1u@2"))),
    Quote(RESULTS_MD, "(on the 48 people of the sessions by {0:.2f} [{1:.2f}, {2:.2f}] and {3:.2f} [{4:.2f}, {5:.2f}];",
          lambda: tuple(x for p in ("staircase:1u1d@2", "staircase:2d1u@2")
                        for x in (-d_best("sessions", p)[0], -d_best("sessions", p)[2], -d_best("sessions", p)[1]))),
    Quote(RESULTS_MD, "Per cluster (mean over seeds): fixed level 2 scores {0:.2f} / {1:.2f} / {2:.2f}, the performance "
                      "learner {3:.2f} / {4:.2f} / {5:.2f}, the oracle {6:.2f} / {7:.2f} / {8:.2f}.",
          lambda: tuple(by_cluster("clusters", p)[c] for p in ("fixed:2", "usp:performance", "oracle")
                        for c in ("1", "2", "3"))),
    Quote(RESULTS_MD, "level 4 for cluster 3 ({0:.2f})", lambda: (by_cluster("clusters", "fixed:4")["3"],)),
    Quote(RESULTS_MD, "performance {0:.2f}, Q-augmentation {1:.2f}, shaping {2:.2f}, against {3:.2f} for the best fixed "
                      "level (`docs/results/clusters-shipped`)",
          lambda: tuple(evaluation("clusters-shipped", p)["score"]
                        for p in ("usp:performance", "usp:qaug", "usp:shaping", "best-fixed"))),
    Quote(RESULTS_MD, "the learners score lower: performance {0:.2f}, shaping {1:.2f}, Q-augmentation {2:.2f} "
                      "(`docs/results/sessions-informed`)",
          lambda: tuple(evaluation("sessions-informed", p)["score"] for p in ("usp:performance", "usp:shaping", "usp:qaug"))),
    # user models and their variants (docs/results/user-models, docs/results/user_model_variants.json)
    *[Quote(RESULTS_MD, f"| {label} | {{0:.4f}} [{{1:.4f}}, {{2:.4f}}] |",
            lambda m=model: (user_models(m)["log_lik_per_turn"], *user_models(m)["log_lik_ci"]))
      for model, label in (("per-level", "per level (Beta prior per level from the other sessions)"),
                           ("clusters", "clusters (posterior mixture of the 3 clusters' level rates)"))],
    Quote(RESULTS_MD, "| **{0:.4f}** [{1:.4f}, {2:.4f}] | **{3:+.4f} [{4:+.4f}, {5:+.4f}]** | {6:.3f} |",
          lambda: (user_models("psychometric")["log_lik_per_turn"], *user_models("psychometric")["log_lik_ci"],
                   user_models("psychometric")["d_per_level"], *user_models("psychometric")["d_per_level_ci"],
                   user_models("psychometric")["calibration"]["ece"])),
    Quote(RESULTS_MD, "It is less well calibrated ({0:.3f} against {1:.3f}).",
          lambda: (user_models("psychometric")["calibration"]["ece"], user_models("per-level")["calibration"]["ece"])),
    *[Quote(RESULTS_MD, "| {0:.4f} [{1:.4f}, {2:.4f}] | ", lambda i=i: (variant(i)["ll"], *variant(i)["ll_ci"]))
      for i in range(7)],
    *[Quote(RESULTS_MD, "| {0:.3f}, {1:+.3f} [{2:.3f}, {3:.3f}] | {4:.3f}, {5:+.3f} [{6:.3f}, {7:.3f}] |",
            lambda i=i: tuple(x for o in ("target-p:0.75", "target-rate:0.75")
                              for x in (variant(i)[o]["own rates"]["value"], variant(i)[o]["own rates"]["d_level2"],
                                        *variant(i)[o]["own rates"]["d_level2_ci"])))
      for i in range(7)],
    Quote(RESULTS_MD, "(own rates: {0:.3f} to {1:.3f} under `target-p:0.75`, {2:.3f} to {3:.3f} under `target-rate:0.75`)",
          lambda: tuple(x for o in ("target-p:0.75", "target-rate:0.75")
                        for x in spread(variant(i)[o]["own rates"]["value"] for i in range(7)))),
    # "What it shows" (personalisation)
    Quote(RESULTS_MD, "where there is something to win ({0:.1f} points between the best fixed level and the oracle), the "
                      "whole pipeline without an assessment beats the best fixed level by {1:.2f} points [{2:.2f}, {3:.2f}] "
                      "and always level 2 by {4:.2f}",
          lambda: (personalise("personalise-own-rates", "oracle")["d_reference"],
                   personalise("personalise-own-rates", "personalised", 0)["d_reference"],
                   *personalise("personalise-own-rates", "personalised", 0)["d_reference_ci"],
                   personalise("personalise-own-rates", "personalised", 0)["score"]
                   - personalise("personalise-own-rates", "fixed:2")["score"])),
    Quote(RESULTS_MD, "it closes {0:.0f} % of the gap [{1:.0f} %, {2:.0f} %], not the half asked for",
          lambda: tuple(100 * x for x in [personalise("personalise-own-rates", "personalised", 0)["gap_closed"]["share"],
                                          *personalise("personalise-own-rates", "personalised", 0)["gap_closed"]["share_ci"]])),
    Quote(RESULTS_MD, "the oracle is {0:.2f} points above the best fixed level and always level 2 is within {1:.2f} of it",
          lambda: (personalise("personalise", "oracle")["d_reference"],
                   personalise("personalise", "oracle")["score"] - personalise("personalise", "fixed:2")["score"])),
    Quote(RESULTS_MD, "Scores fall by about {0:.1f}-{1:.1f} points per assessment turn",
          lambda: spread((personalise(f, p, 0)["score"] - personalise(f, p, max(lengths(f)))["score"]) / max(lengths(f))
                         for f in PERSONALISE for p in PIPELINES)),
    Quote(RESULTS_MD, "The default six-turn assessment loses {0:.1f} points on the own-rates users and {1:.1f} on the "
                      "data-prior users",
          lambda: (-personalise("personalise-own-rates", "personalised", 6)["d_reference"],
                   -personalise("personalise", "personalised", 6)["d_reference"])),
    Quote(RESULTS_MD, "**The paper's pipeline is the worst choice at every length**, {0:.1f}-{1:.1f} points below the best "
                      "fixed level",
          lambda: _abs_range(personalise(f, "paper", a)["d_reference"] for f in PERSONALISE for a in lengths(f))),
    Quote(RESULTS_MD, "in {0:.0f}-{1:.0f} % of the simulated sessions, column `matched`",
          lambda: tuple(100 * x for x in spread(personalise(f, p, a)["matched"] for f in PERSONALISE
                                                for p in PIPELINES for a in lengths(f)))),
    Quote(RESULTS_MD, "instead is better by {0:.1f}-{1:.1f} points at every length",
          lambda: spread(personalise(f, "posterior-ev", a)["score"] - personalise(f, "paper", a)["score"]
                         for f in PERSONALISE for a in lengths(f))),
    Quote(RESULTS_MD, "({0:+.1f} to {1:+.1f} points over the models as fitted on the own-rates users) and costs a little "
                      "where they do not ({2:.2f} to {3:.1f} on the data-prior users: the probes)",
          lambda: (*spread(personalise("personalise-own-rates", "personalised", a)["score"]
                           - personalise("personalise-own-rates", "posterior-ev", a)["score"]
                           for a in lengths("personalise-own-rates")),
                   *sorted((personalise("personalise", "personalised", a)["score"]
                            - personalise("personalise", "posterior-ev", a)["score"] for a in lengths("personalise")),
                           reverse=True)[::len(lengths("personalise")) - 1])),
    Quote(RESULTS_MD, "the nearest cluster is the most likely model after 6 turns for {0:.0f} % of the {1} people from "
                      "outcomes alone and {2:.0f} % with the engagement likelihood; its probability changes by "
                      "{3:+.3f} [{4:.3f}, {5:.3f}] after 6 turns, {6:+.3f} [{7:.3f}, {8:.3f}] after 12 and "
                      "{9:+.3f} [{10:.3f}, {11:.3f}] after 25 (after 25 turns the accuracy even drops, {12:.0f} % → {13:.0f} %;",
          lambda: (100 * engagement("personalise", 6)["outcomes"]["accuracy"], engagement("personalise", 6)["people"],
                   100 * engagement("personalise", 6)["outcomes+engagement"]["accuracy"],
                   *(x for t in (6, 12, 25) for x in (engagement("personalise", t)["p_true_diff"],
                                                      *engagement("personalise", t)["p_true_diff_ci"])),
                   100 * engagement("personalise", 25)["outcomes"]["accuracy"],
                   100 * engagement("personalise", 25)["outcomes+engagement"]["accuracy"])),
    # --- personalisation.md -----------------------------------------------------------------------
    Quote(PERSONALISATION, "On the published data after 6 turns: {0:.0f} % of the {1} people matched from outcomes alone, "
                           "{2:.0f} % with engagement; the probability of the right cluster {3:+.3f} [{4:.3f}, {5:.3f}]; "
                           "after 25 turns {6:+.3f} [{7:.3f}, {8:.3f}], with the accuracy falling from {9:.0f} % to {10:.0f} %",
          lambda: (100 * engagement("personalise", 6)["outcomes"]["accuracy"], engagement("personalise", 6)["people"],
                   100 * engagement("personalise", 6)["outcomes+engagement"]["accuracy"],
                   engagement("personalise", 6)["p_true_diff"], *engagement("personalise", 6)["p_true_diff_ci"],
                   engagement("personalise", 25)["p_true_diff"], *engagement("personalise", 25)["p_true_diff_ci"],
                   100 * engagement("personalise", 25)["outcomes"]["accuracy"],
                   100 * engagement("personalise", 25)["outcomes+engagement"]["accuracy"])),
    # --- how-to/study.md: in plain words -------------------------------------------------------
    Quote(STUDY, "it loses about {0:.0f} points per session, and {1} participants ({2} per arm) find it {3:.0f} % of the "
                 "time on the score",
          lambda: (-power("sessions", "score: random vs level2")["effect"],
                   min(n for n, p in power("sessions", "score: random vs level2")["power"].items() if p >= 0.8),
                   min(n for n, p in power("sessions", "score: random vs level2")["power"].items() if p >= 0.8) // 3,
                   100 * power("sessions", "score: random vs level2")["power"][
                       min(n for n, p in power("sessions", "score: random vs level2")["power"].items() if p >= 0.8)])),
    Quote(STUDY, "the personalised pipeline scores about {0:.1f} points per session *less*",
          lambda: (-power("sessions", "score: personalised vs level2")["effect"],)),
    Quote(STUDY, "harder levels (success rate {0:.0f} points lower). A study would need about {1:,.0f} participants "
                 "(total) to show that loss with 80 % power for the score, and about {2:,.0f} for the success rate.",
          lambda: (-100 * power("sessions", "success_rate: personalised vs level2")["effect"],
                   round(power("sessions", "score: personalised vs level2")["n80"], -2),
                   round(power("sessions", "success_rate: personalised vs level2")["n80"], -1))),
    Quote(STUDY, "personalisation gains only about {0:.1f} points per session over level 2 here; a study would need "
                 "about {1:,.0f} participants to show it.",
          lambda: (power("clusters", "score: personalised vs level2")["effect"],
                   round(power("clusters", "score: personalised vs level2")["n80"], -2))),
    Quote(STUDY, "(effects of {0:.3f}-{1:.3f} on a 0-1 scale), and no N in the range reaches even {2}",
          lambda: (*sorted(abs(power("sessions", f"engagement: {a} vs level2")["effect"]) for a in ("personalised", "random")),
                   "10 % power" if max(p for a in ("personalised", "random")
                                       for p in power("sessions", f"engagement: {a} vs level2")["power"].values()) < 0.10
                   else "(some N reaches 10 %)")),
]


def _page(name: str) -> str:
    return " ".join((ROOT / name).read_text().split())


def _id(q: Quote) -> str:
    return f"{Path(q.page).stem}: {re.sub(r'[{][^}]*[}]', '#', q.text)[:60]}"


@pytest.mark.parametrize("quote", CASES, ids=[_id(q) for q in CASES])
def test_the_page_quotes_the_stored_output(quote):
    want = quote.expected()
    assert want in _page(quote.page), f"{quote.page} does not say (from the stored outputs):\n  {want}"


def test_every_results_page_is_covered():
    assert {q.page for q in CASES} == {SUMMARY, RESULTS_MD, STUDY, PERSONALISATION}
    assert len(CASES) >= 40


def test_a_drifted_output_or_page_number_fails(monkeypatch):
    """The check can fail: one stored value changed, or one number of the page changed, breaks its quote."""
    quote = next(q for q in CASES if "no room at all" in q.text)
    want, page = quote.expected(), _page(quote.page)
    assert want in page
    assert want.replace("0.12", "0.13") not in page.replace(want, want.replace("0.12", "0.13")).replace(
        want.replace("0.12", "0.13"), want)  # the page's number changed back: sanity of the replacement
    drifted = page.replace(want, want.replace("0.12", "0.13"))  # the page drifts over the output
    assert want != want.replace("0.12", "0.13") and want not in drifted
    data = json.loads(json.dumps(stored("docs/results/personalise/personalise.json")))
    next(s for s in data["summary"] if s["policy"] == "oracle")["d_reference"] += 0.01  # the output drifts
    real = stored
    monkeypatch.setattr(sys.modules[__name__], "stored",
                        lambda rel: data if rel == "docs/results/personalise/personalise.json" else real(rel))
    assert quote.expected() != want and quote.expected() not in page
