"""docs/explanation/results.md's generated blocks are what analysis/results_page.py writes from the stored outputs, and
the stored outputs are what the current code computes (a fresh exact recomputation on a few people)."""
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
    assert mod.render(page) == page, "docs/explanation/results.md is stale: run PYTHONPATH=. python analysis/results_page.py"


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
