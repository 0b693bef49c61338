"""Write the generated parts of the results pages from the stored outputs of the repo's commands.

    PYTHONPATH=. python analysis/results_page.py            # rewrite the blocks between the markers
    PYTHONPATH=. python analysis/results_page.py --check    # exit 1 when a page is not what this writes

Every number and every "holds / does not hold" sentence between ``<!-- generated:NAME begin -->`` and
``<!-- generated:NAME end -->`` comes from a stored output (tests/test_results_page.py checks that each page
equals this script's output), so the prose cannot drift from the numbers:

- ``USERS.OBJECTIVE`` (docs/explanation/results.md): the ceiling table of ``docs/results/ceiling-<users>-<objective>/
  personalise.json`` (``analysis/make_ceiling_results.sh``);
- ``multi.USERS.OBJECTIVE``: the several-sessions table of the same output;
- ``holds`` (docs/explanation/results.md, docs/explanation/results-summary.md) and ``holds-short`` (README.md): what holds
  under each objective, in words;
- ``power.USERS`` and ``power-n`` (docs/how-to/study.md, docs/explanation/results-summary.md): the tables of
  ``docs/study/<users>/power.json`` (``analysis/make_power.sh``) and the sample size a gain needs, computed
  by ``PowerReport.n_needed`` from the stored SDs.

A claim "holds" only when its paired 95 % interval over people excludes 0.
"""
from __future__ import annotations

import json
import re
import shlex
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "explanation" / "results.md"
PAGES = (PAGE, ROOT / "docs" / "explanation" / "results-summary.md", ROOT / "docs" / "how-to" / "study.md", ROOT / "README.md")
RESULTS = ROOT / "docs" / "results"
STUDY = ROOT / "docs" / "study"
OBJECTIVES = ("target-p:0.75", "target-rate:0.75")
ALL_OBJECTIVES = ("score",) + OBJECTIVES
USERS = (("own-rates", "own rates (each session's own success per level, shrunk by 2 pseudo-turns)"),
         ("data-prior", "data prior (the default per-session users)"))
WHAT = {"score": "the paper's score, equation (1)",
        "target-p:0.75": "each turn's true success probability near 75 %",
        "target-rate:0.75": "the session's success rate near 75 %"}
LABELS = {"fixed:2": "always level 2", "best-fixed-objective": "best fixed level of the nearest cluster (see below)",
          "pooled-fixed": "level best for the population", "personalised": "personalised pipeline (A = 0)",
          "bayes": "`bayes`, prior: 3 fitted clusters",
          "bayes-psychometric": "`bayes-psychometric` (= live `bayes` under a target)",
          "bayes-loo": "leave-one-out Bayes", "ceiling": "ceiling (Bayes, prior uniform over the users)",
          "staircase-2d1u@2": "staircase 2-down/1-up", "staircase-3d1u@2": "staircase 3-down/1-up",
          "staircase-tuned": "staircase tuned on the other people", "questplus": "QUEST+ (entropy, uniform prior)",
          "questplus-fitted": "QUEST+ (entropy, prior fitted on the other people)",
          "questplus-mean": "QUEST+ placing by its posterior mean", "oracle-objective": "per-user oracle"}
SHORT = {"ceiling": "the ceiling", "bayes-psychometric": "`bayes-psychometric`", "bayes": "`bayes` (clusters)",
         "bayes-loo": "leave-one-out Bayes", "personalised": "the personalised pipeline",
         "best-fixed-objective": "the best fixed level of the nearest cluster (which the held-out session picks)",
         "staircase-2d1u@2": "2-down/1-up", "staircase-3d1u@2": "3-down/1-up",
         "staircase-tuned": "the tuned staircase", "questplus": "QUEST+ (uniform prior)",
         "questplus-fitted": "QUEST+ (fitted prior)"}
MULTI = {"pooled-fixed": "level best for the population (level 2)",
         "explore-commit": "explore in session 1, then commit (prior: all the users)",
         "explore-commit-loo": "the same, prior: the other people",
         "bound": "bound: best first session, then the truth for free", "oracle": "per-user oracle"}
MARK = re.compile(r"(<!-- generated:(?P<name>[\w.:-]+) begin -->\n)(?P<body>.*?)(<!-- generated:(?P=name) end -->)", re.S)
GAIN_POINTS = 1  # decimals the score gain of the power paragraph is rounded to (a design input, stated as such)


def _ci(v, d=3) -> str:
    return "" if not v else f"[{v[0]:.{d}f}, {v[1]:.{d}f}]"


def _d(s, key) -> str:
    return "" if s.get(key) is None else f"{s[key]:+.3f} {_ci(s.get(key + '_ci'))}"


def _share(s) -> str:
    a = s.get("achievable_share") or {}
    if a.get("share") is None:
        return "none: " + (a.get("why") or "no gap")
    return f"{100 * a['share']:.0f} % " + (_ci([100 * x for x in a["share_ci"]], 0) if a.get("share_ci")
                                          else "[unbounded]")


def _verdict(s, key, what, sign=0) -> str:
    """A claim about the paired difference ``key``: ``sign`` +1 claims it above 0, -1 below, 0 either way."""
    d, ci = s.get(key), s.get(key + "_ci")
    if d is None or not ci:
        return f"{what}: not computed"
    side = 1 if ci[0] > 0 else -1 if ci[1] < 0 else 0
    head = f"{what}: {d:+.3f} {_ci(ci)}, "
    if side == 0:
        return head + "**does not hold** (the interval contains 0)"
    where = "above" if side > 0 else "below"
    if sign in (0, side):
        return head + f"**holds** ({where} 0, the interval excludes 0)"
    return head + f"**does not hold: the opposite holds** ({where} 0, the interval excludes 0)"


def _path(users: str, objective: str) -> Path:
    return RESULTS / f"ceiling-{users}-{objective.replace(':', '-')}" / "personalise.json"


def _ceiling(users: str, objective: str) -> dict | None:
    """The ceiling section of a stored output made by the current code (people counted), else None."""
    path = _path(users, objective)
    if not path.exists():
        return None
    j = json.loads(path.read_text())
    c = j["ceiling"]
    out = path.parent.relative_to(ROOT) if path.parent.is_relative_to(ROOT) else path.parent
    c["command"] = _command(j.get("command", ""), str(out))
    return c if any("people" in s and "d_level2" in s for s in c["summary"]) else None


def _by(c: dict) -> dict:
    return {s["policy"]: s for s in c["summary"] if s.get("assessment") in (None, 0)}


def _missing(users: str, objective: str, text: str) -> str:
    path = _path(users, objective)
    return (f"*Not computed yet for {text}, {objective} with the current code: run "
            f"`analysis/make_ceiling_results.sh` (`{path.relative_to(ROOT)}` is missing or older).*\n")


def _command(text: str, out: str) -> str:
    """A stored output's command line with the data folder as ROOT, the output folder as stored, no export."""
    words = shlex.split(text)
    words = [("ROOT" if i and words[i - 1] == "--data" else out if i and words[i - 1] == "--out" else w)
             for i, w in enumerate(words)]
    if "--export-users" in words:
        k = words.index("--export-users")
        words = words[:k] + words[k + 2:]
    return " ".join(words)


def block(objective: str, users: str, text: str) -> str:
    c = _ceiling(users, objective)
    path = _path(users, objective)
    if c is None:
        return _missing(users, objective, text)
    by = _by(c)
    first = next(iter(by.values()))
    out = [f"`{c['command']}`: {text}, objective `{c['objective']}`, {c['turns']}-turn sessions, {first['users']} "
           f"sessions of {first['people']} people (`{path.parent.relative_to(ROOT)}`). Mean over people [95 % t-interval]; "
           "d = policy − reference, paired over people; the ceiling is solved on these users, so intervals "
           "against it are conditional on them. *Best fixed (cluster)*: the level best under the objective on the "
           "participant's nearest cluster, fitted without the participant, but the held-out session itself picks "
           "the cluster, so this reference is partly told who the participant is (most on the data-prior users, "
           "whose rates are shrunk toward that cluster). *Share*: of the ceiling's gain over that level, given "
           "only when the gain's interval excludes 0 (Fieller's interval).", "",
           "| policy | value | d level 2 | d best fixed (cluster) | d ceiling | d leave-one-out Bayes | share |",
           "|---|---|---|---|---|---|---|"]
    for pol, label in LABELS.items():
        if pol in by:
            s = by[pol]
            out.append(f"| {label} | {s['value']:.3f} {_ci(s['value_ci'])} | {_d(s, 'd_level2')} | "
                       f"{_d(s, 'd_reference')} | {_d(s, 'd_ceiling')} | {_d(s, 'd_bayes_loo')} | {_share(s)} |")
    out.append("")
    for pc in c.get("prior_checks", []):
        if "predicted_value" in pc:
            out.append(f"- Prior-predictive check, {pc['prior']}: the prior expects {pc['predicted_value']:.3f} "
                       f"and the plan achieves {pc['achieved_value']:.3f}; success by level predicted "
                       f"{' / '.join(f'{m:.2f}' for m in pc['prior_mean'])} (SD "
                       f"{' / '.join(f'{m:.2f}' for m in pc['prior_sd'])}), users "
                       f"{' / '.join(f'{m:.2f}' for m in pc['users_mean'])} (SD "
                       f"{' / '.join(f'{m:.2f}' for m in pc['users_sd'])}).")
    nc = c.get("noise_corrected_oracle")
    if nc:
        o, p = nc["own_rates"], nc["population"]
        out.append(f"- Oracle gap of a fixed level per person over the best fixed level: {o['oracle_gap']:.3f} "
                   f"{_ci(o['oracle_gap_ci'])} on own rates; {p['oracle_gap']:.3f} noise-corrected (true rates "
                   "spread as the beta-binomial fit supports, between-person SD by level "
                   f"{' / '.join(f'{x:.2f}' for x in nc['between_sd'])})"
                   + ("" if nc.get("noise_share") is None else
                      f": {100 * nc['noise_share']:.0f} % of the own-rates gap is the noise of a few turns per level")
                   + ".")
    if "oracle-objective" in by and "ceiling" in by:
        out.append(f"- Per-user oracle {by['oracle-objective']['value']:.3f}, ceiling {by['ceiling']['value']:.3f}.")
    out += ["", "What holds and what does not (each a paired 95 % interval over people):", ""]
    planner = by.get("bayes-psychometric", {})
    checks = [(planner, "d_level2", "`bayes-psychometric` beats always level 2", 1),
              (planner, "d_reference", "`bayes-psychometric` beats the best fixed level of the nearest cluster", 1),
              (planner, "d_bayes_loo", "`bayes-psychometric` differs from leave-one-out Bayes", 0),
              (planner, "d_ceiling", "`bayes-psychometric` falls short of the ceiling", -1),
              (by.get("ceiling", {}), "d_level2", "the ceiling is above always level 2 (something to win)", 1)]
    for pol in ("staircase-2d1u@2", "staircase-3d1u@2", "staircase-tuned", "questplus", "questplus-fitted"):
        if pol in by:
            checks.append((by[pol], "d_ceiling", f"{LABELS[pol]} falls short of the ceiling", -1))
    out += [f"- {_verdict(s, k, w, sign)}" for s, k, w, sign in checks if s]
    return "\n".join(out) + "\n"


def multi_block(objective: str, users: str, text: str) -> str:
    c = _ceiling(users, objective)
    if c is None:
        return _missing(users, objective, text)
    rows = c.get("multi_session")
    if not rows:
        return (f"*Several sessions: {c.get('multi_session_note') or 'not computed'} "
                f"(`{_path(users, objective).parent.relative_to(ROOT)}`).*\n")
    sessions = sorted({r["sessions"] for r in rows})
    at = {(r["sessions"], r["policy"]): r for r in rows}
    out = [f"Several sessions of one participant, {text}, objective `{c['objective']}` "
           f"(`{_path(users, objective).parent.relative_to(ROOT)}`, {rows[0]['people']} people): value per session "
           "[95 % t-interval]; d = minus the level best for the population, paired over people; share of the "
           "oracle's gap over that level (only when the gap's interval excludes 0), Fieller's 95 % interval over people.", "",
           "| policy | " + " | ".join(f"{n} session{'s' * (n > 1)}" for n in sessions) + " |",
           "|---|" + "---|" * len(sessions)]
    for pol, label in MULTI.items():
        cells = []
        for n in sessions:
            r = at.get((n, pol))
            if r is None:
                cells.append("")
                continue
            cell = f"{r['value_per_session']:.3f} {_ci(r['value_ci'])}"
            if pol not in ("pooled-fixed",):
                cell += f"; d {r['d_best_fixed']:+.3f} {_ci(r.get('d_best_fixed_ci'))}"
            if pol not in ("pooled-fixed", "oracle") and r.get("oracle_share") is not None:
                cell += f"; {100 * r['oracle_share']:.0f} % {_ci([100 * x for x in r['oracle_share_ci']], 0)}" \
                    if r.get("oracle_share_ci") else f"; {100 * r['oracle_share']:.0f} %"
            cells.append(cell)
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


EVAL_LABELS = {"fixed:1": "fixed level 1", "fixed:2": "fixed level 2", "fixed:3": "fixed level 3",
               "fixed:4": "fixed level 4", "best-fixed": "best fixed level (chosen on the training simulators)",
               "random": "random", "staircase:1u1d@2": "staircase 1-up/1-down from 2",
               "staircase:2d1u@2": "staircase 2-down/1-up from 2", "usp:performance": "learner, performance (frozen)",
               "usp:shaping": "learner, reward shaping", "usp:qaug": "learner, Q-augmentation",
               "usp-learning:performance": "learner, performance, still learning",
               "usp-learning:shaping": "learner, reward shaping, still learning",
               "usp-learning:qaug": "learner, Q-augmentation, still learning", "oracle": "oracle (finite-horizon optimum)"}
EVAL_SETS = ("clusters", "level-only", "clusters-tested", "sessions")


def _evaluation(name: str) -> dict:
    return json.loads((RESULTS / name / "evaluation.json").read_text())


def eval_block(name: str) -> str:
    """The score table of one stored ``nao-trainer evaluate`` output (docs/results/NAME/evaluation.json)."""
    j = _evaluation(name)
    command = _command(j["command"], f"docs/results/{name}")
    rows = j["summary"]
    if rows[0].get("unit") == "people":
        head = (f"`{command}` ({rows[0]['users']} sessions of {rows[0]['people']} people; "
                f"`docs/results/{name}/evaluation.json`). Score per 25-turn session, mean over people [95 % t-interval "
                "over people: a person's sessions and seeds averaged first]; regret = the user's oracle score minus the "
                "policy's; d = policy − best fixed level, paired over people.")
    else:
        head = (f"`{command}` ({rows[0]['n']} (user, seed) rows per policy, {rows[0]['users']} users; "
                f"`docs/results/{name}/evaluation.json`). Score per 25-turn session [95 % t-interval over the rows]; "
                "regret = the user's oracle score minus the policy's; d = policy − best fixed level, paired.")
    out = [head, "",
           "| policy | score [95 % CI] | regret | d best fixed [95 % CI] | engagement |", "|---|---|---|---|---|"]
    for s in rows:
        v = s.get("vs_reference") or {}
        d = "" if s["policy"] == v.get("reference") or "score_diff" not in v else \
            f"{v['score_diff']:+.2f} {_ci(v.get('score_diff_ci'), 2)}"
        out.append(f"| {EVAL_LABELS.get(s['policy'], s['policy'])} | {s['score']:.2f} {_ci(s['score_ci'], 2)} | "
                   f"{s['regret']:.2f} | {d} | {s['engagement']:.3f} |")
    return "\n".join(out) + "\n"


def claims_block() -> str:
    """The engagement-feedback claim, retested: shaping or Q-augmentation minus the performance-only learner."""
    names = {"clusters": "clusters (authors' fit)", "level-only": "level-only", "clusters-tested": "tested-effects clusters",
             "sessions": "sessions (leave one person out)"}
    over = {name: "people" if any(c.get("unit") == "people" for c in _evaluation(name).get("claims", [])) else "rows"
            for name in EVAL_SETS}
    people = [names[n].split(" (")[0] for n in EVAL_SETS if over[n] == "people"]
    unit = "Paired over (user, seed) rows" if not people else \
        f"Paired over (user, seed) rows, over people for the {_list(people)} (a person's sessions and seeds averaged)"
    out = [f"{unit}; frozen learners (`claims` of each `evaluation.json`):", "",
           "| user set | shaping: score | shaping: engagement | Q-aug.: score | Q-aug.: engagement |", "|---|---|---|---|---|"]
    for name in EVAL_SETS:
        by = {c["a"]: c for c in _evaluation(name).get("claims", []) if c["b"] == "usp:performance"}
        cells = []
        for a in ("usp:shaping", "usp:qaug"):
            c = by.get(a)
            cells += ["", ""] if c is None else [f"{c['score_diff']:+.2f} {_ci(c['score_diff_ci'], 2)}",
                                                f"{c['engagement_diff']:+.4f} {_ci(c['engagement_diff_ci'], 4)}"]
        out.append(f"| {names[name]} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


PIPELINES = {"paper": "paper: most likely cluster → its policy", "posterior-ev": "posterior expected value, models as fitted",
             "personalised": "whole pipeline (+ per-level Beta, probes)"}


def personalise_block(name: str) -> str:
    """The assessment-length table of one stored ``evaluate --personalise`` output (docs/results/NAME)."""
    j = json.loads((RESULTS / name / "personalise.json").read_text())
    command = _command(j["command"], f"docs/results/{name}")
    rows = [s for s in j["summary"]]
    by = {(s["policy"], s.get("assessment")): s for s in rows}
    lengths = [a for a in (0, 3, 6, 9, 12) if ("personalised", a) in by]
    if "people" in rows[0]:
        n, mean, over = f"{rows[0]['users']} sessions of {rows[0]['people']} people", " mean over people,", "over people, "
    else:
        n, mean, over = f"{rows[0]['users']} sessions", "", ""
    out = [f"`{command}` (`docs/results/{name}/personalise.json`; {n}). Score per 25-turn session,{mean} "
           f"assessment turns counted (difference to the best fixed level [95 % t-interval {over}paired]):", "",
           "| policy | " + " | ".join(f"A = {a}" for a in lengths) + " |", "|---|" + "---|" * len(lengths)]
    for pol, label in PIPELINES.items():
        cells = []
        for a in lengths:
            s = by.get((pol, a))
            cells.append("" if s is None else f"{s['score']:.2f} ({s['d_reference']:+.2f} {_ci(s.get('d_reference_ci'), 2)})")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    fixed = [f"{lab} {by[(p, None)]['score']:.2f} {_ci(by[(p, None)]['score_ci'], 2)}"
             for p, lab in (("fixed:2", "always level 2"), ("best-fixed", "best fixed level"),
                            ("generic", "generic policy (pooled data)"), ("oracle", "per-user oracle"))
             if (p, None) in by]
    out += ["", "No assessment: " + "; ".join(fixed) + "."]
    return "\n".join(out) + "\n"


def _holds(s: dict, key: str) -> int:
    """+1 / -1 when the paired interval of ``key`` lies above / below 0, else 0."""
    ci = s.get(key + "_ci")
    return 0 if not ci else (1 if ci[0] > 0 else -1 if ci[1] < 0 else 0)


def _list(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def holds_sentences(objective: str, users: str, short: bool = False) -> str:
    """What holds under one objective on one user set, in words, from its stored output."""
    c = _ceiling(users, objective)
    if c is None:
        return f"**`{objective}`, {users}**: not computed yet with the current code."
    by = _by(c)
    ref = "always level 2"
    pols = [p for p in SHORT if p in by]
    if short:
        pols = [p for p in ("ceiling", "bayes-psychometric", "staircase-2d1u@2", "staircase-tuned") if p in by]
    d = {p: f"{by[p]['d_level2']:+.3f} {_ci(by[p].get('d_level2_ci'))}" for p in pols}
    up = [p for p in pols if _holds(by[p], "d_level2") > 0]
    tie = [p for p in pols if _holds(by[p], "d_level2") == 0]
    down = [p for p in pols if _holds(by[p], "d_level2") < 0]
    head = f"**`{objective}`** ({WHAT.get(c['objective'], c['objective'])}), {users.replace('-', ' ')}"
    if "ceiling" in tie and not up:
        parts = [f"{head}: **nothing beats {ref}, not even the ceiling** ({d['ceiling']})"]
        others = [p for p in tie if p != "ceiling"]
        if others:
            parts[0] += "; " + ", ".join(f"{SHORT[p]} {d[p]}" for p in others)
    else:
        parts = [f"{head}: **beats {ref}**: " + (", ".join(f"{SHORT[p]} {d[p]}" for p in up) or "nothing")]
        if tie:
            parts.append(f"cannot be told from {ref}: " + ", ".join(f"{SHORT[p]} {d[p]}" for p in tie))
    if down:
        parts.append(f"below {ref}: " + ", ".join(f"{SHORT[p]} {d[p]}" for p in down))
    text = "; ".join(parts) + "."
    planner, ceiling = by.get("bayes-psychometric"), by.get("ceiling")
    if planner and ceiling and planner.get("d_ceiling_ci"):
        gap = f"{planner['d_ceiling']:+.3f} {_ci(planner['d_ceiling_ci'])}"
        text += (f" `bayes-psychometric` − ceiling = {gap}: "
                 + ("it falls short of the ceiling." if _holds(planner, "d_ceiling") < 0 else
                    "it cannot be told from the ceiling."))
    return text


def holds_block(short: bool = False) -> str:
    if short:
        lines = [holds_sentences(o, "own-rates", short=True) for o in OBJECTIVES]
        c = _ceiling("own-rates", OBJECTIVES[0])
        people = f"the {_by(c)['fixed:2']['people']} people" if c else "the people"
        lines.append(f"Intervals: paired 95 % over {people} of the published data (own rates: each session's "
                     "own success per level); every table, the data-prior users and the score: "
                     "[docs/explanation/results.md](docs/explanation/results.md).")
        return "\n".join(textwrap.fill(line, 150, initial_indent="- ", subsequent_indent="  ",
                                       break_on_hyphens=False, break_long_words=False) for line in lines) + "\n"
    out = ["Written by `analysis/results_page.py` from the stored outputs (each d = policy − always level 2, "
           "a paired 95 % interval over people; a claim holds only when the interval excludes 0):", ""]
    for users, _ in USERS:
        for o in ALL_OBJECTIVES:
            if o == "score" and _ceiling(users, o) is None:
                continue
            out.append(f"- {holds_sentences(o, users)}")
    return "\n".join(out) + "\n"


def _power_command(users: str) -> str:
    """The line of analysis/make_power.sh that writes docs/study/<users>."""
    script = (ROOT / "analysis" / "make_power.sh").read_text().replace("\\\n", " ")
    for line in script.splitlines():
        if line.strip().startswith("nao-trainer study power") and f"--out docs/study/{users}" in line:
            return " ".join(shlex.split(line.replace('"$DATA"', "DATA")))
    raise SystemExit(f"results_page: analysis/make_power.sh has no study power command for docs/study/{users}")


def _power_report(users: str):
    from nao_trainer.study.power import PowerReport

    j = json.loads((STUDY / users / "power.json").read_text())
    arms = {a for key in j["power"] for a in key.split(": ", 1)[1].split(" vs ")}
    return PowerReport(arms=len(arms), name=j["protocol"], protocol_sha256=j["protocol_sha256"], ns=j["ns"],
                       reps=j["reps"], alpha=j["alpha"], users=j["users"], drift=j["drift"], power=j["power"], effect=j["effect"],
                       sd=j["sd"], sd_ref=j.get("sd_ref", {})), j


def power_block(users: str) -> str:
    rep, j = _power_report(users)
    out = [f"`{_power_command(users)}` (in `analysis/make_power.sh`; output `docs/study/{users}/power.txt`, "
           f"protocol sha256 {j['protocol_sha256'][:12]}, {j['reps']} simulated studies per N, test: "
           f"{j.get('test', 'one variance pooled over the arms (older run)')}). Power per total N (all arms); the "
           "effect is the mean estimated arm − reference at the largest N; SDs of participant means in the arm / "
           "the reference arm:", "",
           "| outcome: comparison | " + " | ".join(f"N={n}" for n in rep.ns) + " | N for 80 % | effect | SDs |",
           "|---|" + "---|" * (len(rep.ns) + 3)]
    for key in sorted(rep.power):
        sds = f"{rep.sd[key]:.2f} / {rep.sd_ref.get(key, rep.sd[key]):.2f}"
        out.append(f"| {key} | " + " | ".join(f"{p:.2f}" for p in rep.power[key])
                   + f" | {rep.n_for_80(key)} | {rep.effect[key][-1]:+.3f} | {sds} |")
    return "\n".join(out) + "\n"


def _score_gain() -> tuple[float, str] | None:
    """The ceiling's gain over always level 2 on the score, own rates, from its stored output."""
    path = _path("own-rates", "score")
    if not path.exists():
        return None
    c = json.loads(path.read_text())["ceiling"]
    by = _by(c)
    if "ceiling" not in by or "fixed:2" not in by:
        return None
    s = by["fixed:2"]
    gain = -s["d_ceiling"]
    ci = s.get("d_ceiling_ci")
    return gain, (f"{gain:+.2f}" + ("" if not ci else f" [{-ci[1]:.2f}, {-ci[0]:.2f}]")
                  + f", `{path.parent.relative_to(ROOT)}`")


def power_n_block() -> str:
    rep, _ = _power_report("sessions")
    key = "score: personalised vs level2"
    sd, sd_ref = rep.sd[key], rep.sd_ref.get(key, rep.sd[key])
    found = _score_gain()
    if found is None:
        return "*The score's ceiling output (own rates) is missing: run `analysis/make_ceiling_results.sh`.*\n"
    gain, where = found
    delta = round(gain, GAIN_POINTS)
    both = rep.n_needed(delta, sd, arms=1, sd_ref=sd_ref)
    same = rep.n_needed(delta, sd_ref, arms=1, sd_ref=sd_ref)
    text = (f"A gain of {delta:g} points per session (the ceiling's gain over always level 2 on the score, own "
            f"rates: {where}, rounded) needs about **{both:,} participants per arm** for 80 % power with the two "
            f"arms' own SDs of participant means in `docs/study/sessions/power.json` ({sd:.2f} personalised, "
            f"{sd_ref:.2f} level 2), or {same:,} if the personalised arm spread like level 2 "
            "(n per arm = (z_0.975 + z_0.8)² (sd² + sd_ref²) / δ², `PowerReport.n_needed`).")
    return textwrap.fill(text, 110, break_on_hyphens=False, break_long_words=False) + "\n"


def render_block(name: str, where: str = "docs/explanation/results.md") -> str:
    if name == "holds":
        return holds_block()
    if name == "holds-short":
        return holds_block(short=True)
    if name == "power-n":
        return power_n_block()
    if name == "claims":
        return claims_block()
    if name.startswith("personalise."):
        return personalise_block(name.split(".", 1)[1])
    if name.startswith("eval."):
        return eval_block(name.split(".", 1)[1])
    if name.startswith("power."):
        return power_block(name.split(".", 1)[1])
    multi = name.startswith("multi.")
    users, _, objective = (name[6:] if multi else name).partition(".")
    text = dict(USERS).get(users)
    if text is None or objective not in ALL_OBJECTIVES:
        raise SystemExit(f"results_page: unknown block {name!r} in {where}")
    return (multi_block if multi else block)(objective, users, text)


def render(page: str, where: str = "docs/explanation/results.md") -> str:
    return MARK.sub(lambda m: m.group(1) + render_block(m.group("name"), where) + m.group(4), page)


def main(argv: list[str]) -> int:
    stale = []
    for path in PAGES:
        page = path.read_text()
        new = render(page, str(path.relative_to(ROOT)))
        if new != page:
            stale.append(path)
            if "--check" not in argv:
                path.write_text(new)
    if "--check" in argv and stale:
        print("results_page: " + ", ".join(str(p.relative_to(ROOT)) for p in stale)
              + " not what analysis/results_page.py writes; run it", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
