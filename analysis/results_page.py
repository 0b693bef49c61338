"""Write the generated part of docs/explanation/results.md from the stored outputs of analysis/make_ceiling_results.sh.

    PYTHONPATH=. python analysis/results_page.py            # rewrite the blocks between the markers
    PYTHONPATH=. python analysis/results_page.py --check    # exit 1 when the page is not what this writes

Every number and every "holds / does not hold" sentence between ``<!-- generated:NAME begin -->`` and
``<!-- generated:NAME end -->`` comes from ``docs/results/ceiling-<users>-<objective>/personalise.json``
(tests/test_results_page.py checks that the page equals this script's output), so the prose cannot
drift from the numbers. A claim "holds" only when its paired 95 % interval over people excludes 0.
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "explanation" / "results.md"
RESULTS = ROOT / "docs" / "results"
OBJECTIVES = ("target-p:0.75", "target-rate:0.75")
USERS = (("own-rates", "own rates (each session's own success per level, shrunk by 2 pseudo-turns)"),
         ("data-prior", "data prior (the default per-session users)"))
LABELS = {"fixed:2": "always level 2", "best-fixed-objective": "best fixed level, chosen on training data",
          "pooled-fixed": "level best for the population", "personalised": "personalised pipeline (A = 0)",
          "bayes": "`bayes`, prior: 3 fitted clusters",
          "bayes-psychometric": "`bayes-psychometric` (= live `bayes` under a target)",
          "bayes-loo": "leave-one-out Bayes", "ceiling": "ceiling (Bayes, prior uniform over the users)",
          "staircase-2d1u@2": "staircase 2-down/1-up", "staircase-3d1u@2": "staircase 3-down/1-up",
          "staircase-tuned": "staircase tuned on the other people", "questplus": "QUEST+ (entropy, uniform prior)",
          "questplus-fitted": "QUEST+ (entropy, prior fitted on the other people)",
          "questplus-mean": "QUEST+ placing by its posterior mean", "oracle-objective": "per-user oracle"}
MARK = re.compile(r"(<!-- generated:(?P<name>[\w.:-]+) begin -->\n)(?P<body>.*?)(<!-- generated:(?P=name) end -->)", re.S)


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


def _verdict(s, key, what) -> str:
    d, ci = s.get(key), s.get(key + "_ci")
    if d is None or not ci:
        return f"{what}: not computed"
    held = ci[0] > 0 or ci[1] < 0
    sign = "above" if d > 0 else "below"
    return (f"{what}: {d:+.3f} {_ci(ci)}, " + (f"**holds** ({sign}, the interval excludes 0)" if held
                                                else "**does not hold** (the interval contains 0)"))


def block(objective: str, users: str, text: str) -> str:
    path = RESULTS / f"ceiling-{users}-{objective.replace(':', '-')}" / "personalise.json"
    if not path.exists():
        return (f"*Not computed yet for {text}, {objective}: run `analysis/make_ceiling_results.sh` "
                f"(`{path.relative_to(ROOT)}` is missing); the numbers elsewhere on this page are older.*\n")
    c = json.loads(path.read_text())["ceiling"]
    by = {s["policy"]: s for s in c["summary"] if s.get("assessment") in (None, 0)}
    first = next(iter(by.values()))
    out = [f"{text}, objective `{c['objective']}`, {c['turns']}-turn sessions, {first['users']} sessions of "
           f"{first['people']} people (`{path.parent.relative_to(ROOT)}`). Mean over people [95 % t-interval]; "
           "d = policy − reference, paired over people; the ceiling is solved on these users, so intervals "
           "against it are conditional on them; a share of the ceiling's gain over the best fixed level is "
           "given only when that gain's interval excludes 0 (Fieller's interval).", "",
           "| policy | value | d level 2 | d best fixed (train) | d ceiling | d leave-one-out Bayes | share |",
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
    checks = [(planner, "d_level2", "`bayes-psychometric` beats always level 2"),
              (planner, "d_reference", "`bayes-psychometric` beats the best fixed level chosen on training data"),
              (planner, "d_bayes_loo", "`bayes-psychometric` differs from leave-one-out Bayes"),
              (planner, "d_ceiling", "`bayes-psychometric` falls short of the ceiling"),
              (by.get("ceiling", {}), "d_level2", "the ceiling is above always level 2 (something to win)")]
    for pol in ("staircase-2d1u@2", "staircase-3d1u@2", "staircase-tuned", "questplus", "questplus-fitted"):
        if pol in by:
            checks.append((by[pol], "d_ceiling", f"{LABELS[pol]} falls short of the ceiling"))
    out += [f"- {_verdict(s, k, w)}" for s, k, w in checks if s]
    return "\n".join(out) + "\n"


def render(page: str) -> str:
    def one(m: re.Match) -> str:
        name = m.group("name")
        users, objective = name.split(".", 1)
        text = dict(USERS).get(users)
        if text is None or objective not in OBJECTIVES:
            raise SystemExit(f"results_page: unknown block {name!r} in {PAGE.name}")
        return m.group(1) + block(objective, users, text) + m.group(4)
    return MARK.sub(one, page)


def main(argv: list[str]) -> int:
    page = PAGE.read_text()
    new = render(page)
    if "--check" in argv:
        if new != page:
            print(f"results_page: {PAGE.relative_to(ROOT)} is not what analysis/results_page.py writes; run it",
                  file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(new)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
