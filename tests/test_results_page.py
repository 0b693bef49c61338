"""The results pages' generated blocks (docs/explanation/results.md, docs/explanation/results-summary.md, docs/how-to/study.md,
README.md) are what analysis/results_page.py writes from the stored outputs, and the stored outputs are what the
current code computes (a fresh exact recomputation on a few people)."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


def _script():
    spec = importlib.util.spec_from_file_location("results_page", ROOT / "analysis" / "results_page.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_results_page_is_what_the_script_writes_from_the_stored_outputs():
    page = (ROOT / "docs" / "explanation" / "results.md").read_text()
    mod = _script()
    names = [m.group("name") for m in mod.MARK.finditer(page)]
    assert {f"{u}.{o}" for u, _ in mod.USERS for o in mod.OBJECTIVES} <= set(names)
    assert "holds" in names and "claims" in names
    assert {f"eval.{name}" for name in mod.EVAL_SETS} <= set(names)
    assert mod.render(page) == page, "docs/explanation/results.md is stale: run PYTHONPATH=. python analysis/results_page.py"


def test_every_objective_and_user_set_is_computed_with_the_current_code():
    """Both objectives on both user sets have a stored output of the current code (people counted)."""
    mod = _script()
    for users, _ in mod.USERS:
        for objective in mod.OBJECTIVES:
            assert mod._ceiling(users, objective) is not None, (users, objective)
    assert "Not computed yet" not in (ROOT / "docs" / "explanation" / "results.md").read_text()


@pytest.mark.parametrize("name,blocks", [("docs/explanation/results-summary.md", {"holds", "power-n"}),
                                         ("docs/how-to/study.md", {"power.sessions", "power.clusters", "power-n"}),
                                         ("README.md", {"holds-short"})])
def test_the_other_pages_are_what_the_script_writes(name, blocks):
    mod = _script()
    page = (ROOT / name).read_text()
    assert blocks <= {m.group("name") for m in mod.MARK.finditer(page)}, name
    assert mod.render(page, name) == page, f"{name} is stale: run PYTHONPATH=. python analysis/results_page.py"


@pytest.mark.parametrize("users", ["sessions", "clusters"])
def test_the_power_tables_are_what_study_power_printed(users):
    """docs/how-to/study.md's power table (rebuilt from power.json) has power.txt's rows, as `study power` printed them."""
    mod = _script()
    printed = {}
    for line in (ROOT / "docs" / "study" / users / "power.txt").read_text().splitlines()[2:]:
        if not line or line.startswith(("mean estimated", " ", "note:")):
            break
        key, rest = line[:42].strip(), line[42:].split()
        printed[key] = ([float(x) for x in rest[:6]], " ".join(rest[6:]))
    rows = [r for r in mod.power_block(users).splitlines() if r.startswith("| ") and " vs " in r.split("|")[1]]
    assert len(rows) == len(printed) > 0
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert [float(x) for x in cells[1:7]] == printed[cells[0]][0], cells[0]
        assert cells[7] == printed[cells[0]][1], cells[0]
    assert mod._power_command(users) in mod.power_block(users)


def test_the_sample_size_paragraph_is_the_normal_formula_on_the_stored_sds():
    mod = _script()
    power = json.loads((ROOT / "docs" / "study" / "sessions" / "power.json").read_text())
    key = "score: personalised vs level2"
    gain, _ = mod._score_gain()
    delta = round(gain, mod.GAIN_POINTS)
    z = 1.959963984540054 + 0.8416212335729143
    both = int(np.ceil(z ** 2 * (power["sd"][key] ** 2 + power["sd_ref"][key] ** 2) / delta ** 2))
    same = int(np.ceil(z ** 2 * 2 * power["sd_ref"][key] ** 2 / delta ** 2))
    text = " ".join(mod.power_n_block().split())
    assert f"about **{both:,} participants per arm**" in text and f"or {same:,} if" in text


def _fake_output(tmp_path, objective, d_level2):
    """A stored output with the given paired differences to level 2 (value, interval) per policy."""
    summary = [{"policy": "fixed:2", "assessment": None, "users": 5, "people": 4, "value": -1.0,
                "value_ci": [-1.2, -0.8], "d_level2": 0.0, "d_level2_ci": [0.0, 0.0]}]
    for pol, (d, ci) in d_level2.items():
        summary.append({"policy": pol, "assessment": None, "users": 5, "people": 4, "value": -1.0 + d,
                        "value_ci": [-1.2 + d, -0.8 + d], "d_level2": d, "d_level2_ci": ci,
                        "d_ceiling": -0.01, "d_ceiling_ci": [-0.03, 0.01]})
    out = tmp_path / f"ceiling-own-rates-{objective.replace(':', '-')}"
    out.mkdir(parents=True)
    (out / "personalise.json").write_text(json.dumps({"ceiling": {"objective": objective, "turns": 25,
                                                                   "summary": summary, "rows": []}}))


def test_what_holds_follows_the_intervals(tmp_path, monkeypatch):
    mod = _script()
    monkeypatch.setattr(mod, "RESULTS", tmp_path)
    _fake_output(tmp_path, "target-p:0.75", {"ceiling": (0.09, [-0.01, 0.19]), "bayes-psychometric": (0.07, [-0.04, 0.18]),
                                             "staircase-2d1u@2": (-0.8, [-1.0, -0.5])})
    _fake_output(tmp_path, "target-rate:0.75", {"ceiling": (0.95, [0.75, 1.14]), "bayes-psychometric": (0.94, [0.7, 1.1]),
                                                "personalised": (0.1, [-0.06, 0.26])})
    p = mod.holds_sentences("target-p:0.75", "own-rates")
    assert "nothing beats always level 2, not even the ceiling** (+0.090 [-0.010, 0.190])" in p
    assert "below always level 2: 2-down/1-up -0.800" in p and "cannot be told from the ceiling" in p
    r = mod.holds_sentences("target-rate:0.75", "own-rates")
    assert "**beats always level 2**: the ceiling +0.950 [0.750, 1.140], `bayes-psychometric` +0.940" in r
    assert "cannot be told from always level 2: the personalised pipeline +0.100" in r
    assert "nothing beats" not in r


def test_a_claim_holds_only_in_its_direction():
    mod = _script()
    s = {"d": -0.25, "d_ci": [-0.3, -0.2]}
    assert "**does not hold: the opposite holds** (below 0" in mod._verdict(s, "d", "beats", 1)
    assert "**holds** (below 0" in mod._verdict(s, "d", "falls short", -1)
    assert "**holds** (below 0" in mod._verdict(s, "d", "differs", 0)
    assert "**does not hold** (the interval contains 0)" in mod._verdict({"d": 0.1, "d_ci": [-0.1, 0.3]}, "d", "x", 1)


def _stored() -> list[Path]:
    return sorted(ROOT.glob("docs/results/ceiling-*-target-*-0.75/personalise.json"))


@pytest.mark.parametrize("path", _stored(), ids=lambda p: p.parent.name)
def test_the_stored_outputs_are_what_the_code_computes_now(path):
    """Three people's staircase and fixed-level rows, recomputed exactly from their rates per level."""
    from nao_trainer.core import objective
    from nao_trainer.experiments import adaptive

    c = json.loads(path.read_text())["ceiling"]
    obj = objective.parse(c["objective"])
    rates: dict[str, dict[int, float]] = {}
    for r in c["rows"]:
        if "level" in r:
            rates.setdefault(r["user"], {})[r["level"]] = r["success"]
    stored = {(r["user"], r["policy"]): r["utility"] for r in c["rows"]}
    checked = 0
    for user, by in sorted(rates.items()):
        if len(by) < 4 or checked == 3:
            continue
        p = np.array([by[lv] for lv in (1, 2, 3, 4)])
        got = adaptive.staircase_exact(2, 2, p, c["turns"], obj)["utility"]
        assert got == pytest.approx(stored[(user, "staircase-2d1u@2")], abs=1e-6), user
        assert obj.fixed_value(p, c["turns"])[0] == pytest.approx(stored[(user, "fixed:1")], abs=1e-6)
        checked += 1
    assert checked == 3


def test_every_generated_table_names_the_command_that_made_it():
    """Each ceiling block opens with its stored output's command (data folder as ROOT), objective and folder."""
    mod = _script()
    for users, text in mod.USERS:
        for objective in mod.ALL_OBJECTIVES:
            first = mod.block(objective, users, text).splitlines()[0]
            assert first.startswith("`nao-trainer evaluate --personalise --users sessions --data ROOT "), first
            assert f"--objective {objective} " in first and \
                f"--out docs/results/ceiling-{users}-{objective.replace(':', '-')}`" in first, first
    for name in mod.EVAL_SETS:
        assert mod.eval_block(name).startswith("`nao-trainer evaluate --users "), name


@pytest.mark.parametrize("path", sorted(ROOT.glob("docs/results/*/personalise.json")), ids=lambda p: p.parent.name)
def test_the_stored_engagement_summaries_are_their_rows_over_people(path):
    """Every stored `evaluate --personalise` output keeps its per-session engagement measurements, and its
    "does engagement help the match?" table is their summary over people (48), not over the 50 sessions."""
    from nao_trainer.experiments import personalisation, reports

    report = json.loads(path.read_text())
    meas = reports.read_engagement_rows(path.parent / report["engagement_rows_file"])
    assert len({m["user"] for m in meas}) == report["n_users"]
    assert personalisation.summarise_engagement(meas) == report["engagement_information"]
    assert all(e["people"] == 48 and e["sessions"] == 50 for e in report["engagement_information"])
