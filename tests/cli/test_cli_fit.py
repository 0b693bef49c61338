"""`nao-trainer fit`: JSON report, artifacts and figures from the published data; clear errors."""
from __future__ import annotations

import io
import json
import shutil
import sys

import pytest

from _usermodels_data import shared_cache
from nao_trainer.learn import artifacts
from nao_trainer.cli import main

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def fitted(dataset_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit-out")
    cache = shared_cache(tmp_path_factory, "authors2018")
    capture = pytest.MonkeyPatch()
    stdout, stderr = io.StringIO(), io.StringIO()
    capture.setattr(sys, "stdout", stdout)
    capture.setattr(sys, "stderr", stderr)
    try:
        rc = main(["fit", str(dataset_root), "--out", str(out), "--compat", "authors2018", "--json",
                   "--cache", str(cache), "--psychometric", str(out / "psychometric" / "pooled.json")])
    finally:
        capture.undo()
    return rc, out, stdout.getvalue(), stderr.getvalue()


@pytest.mark.slow
def test_fit_json_has_the_issue_structure(fitted):
    rc, _, stdout, _ = fitted
    assert rc == 0
    report = json.loads(stdout)
    assert report["k"] == 3 and report["sessions"] == 50 and report["compat"] == "authors2018"
    assert [c["id"] for c in report["clusters"]] == [1, 2, 3]
    assert sorted(c["size"] for c in report["clusters"]) == [13, 16, 21]
    for c in report["clusters"]:
        for key in ("rmse_performance", "rmse_engagement", "cv_rmse_performance", "cv_rmse_engagement"):
            assert isinstance(c[key], float) and 0 <= c[key] < 0.5, key
        assert len(c["p"]) == len(c["e"]) == 4 and all(0 <= v <= 1 for v in c["p"] + c["e"])
    means = [sum(c["p"]) / 4 for c in report["clusters"]]
    assert means == sorted(means)  # the documented id rule


def test_the_shipped_psychometric_prior_is_what_the_documented_command_writes(fitted):
    """sim/psychometric/pooled.json = `fit DATA --compat authors2018 --psychometric FILE` on the published data."""
    from nao_trainer.learn import psychometric_prior

    rc, out, stdout, _ = fitted
    written = out / "psychometric" / "pooled.json"
    assert rc == 0 and written.read_bytes() == psychometric_prior.DEFAULT_PRIOR.read_bytes()
    doc = json.loads(written.read_text())
    assert doc["dataset_fingerprint"] == artifacts.load_manifest(out)["dataset_fingerprint"]
    assert (doc["sessions"], doc["turns"]) == (50, 1250)
    model = psychometric_prior.load_prior()
    assert json.loads(stdout)["psychometric"] == {"file": str(written), **model.__dict__}
    assert 5.0 < model.mu < 9.0 and model.sigma > 0


def test_fit_writes_loadable_artifacts_and_figures(fitted):
    rc, out, stdout, stderr = fitted
    manifest = artifacts.load_manifest(out)
    assert manifest["k"] == 3 and manifest["library_versions"]["numpy"]
    assert len(manifest["dataset_fingerprint"]) == 64
    for cid in ("1", "2", "3"):
        sim = artifacts.load_simulator(cid, out)
        assert sim.metadata["dataset_fingerprint"] == manifest["dataset_fingerprint"]
    for name in ("users.png", "clusters.png"):
        assert (out / name).read_bytes()[:8] == PNG
    assert "K-means K=3" in stderr  # progress goes to stderr, JSON alone to stdout


def test_fit_from_an_imported_table_gives_the_same_models(fitted, dataset_root, tmp_path_factory, tmp_path, capsys):
    _, out, _, _ = fitted
    table = tmp_path / "turns.csv"
    cache = shared_cache(tmp_path_factory, "authors2018")
    assert main(["import", str(dataset_root), "--out", str(table), "--compat", "authors2018", "--cache", str(cache),
                 "-q"]) == 0
    assert main(["fit", str(table), "--out", str(tmp_path / "m"), "--no-figures"]) == 0
    assert not (tmp_path / "m" / "users.png").exists()
    for cid in ("1", "2", "3"):
        again = artifacts.load_simulator(cid, tmp_path / "m")
        assert again.fingerprint() == artifacts.load_simulator(cid, out).fingerprint()
    assert main(["import", str(out), "--out", str(tmp_path / "x.csv"), "-q"]) == 2  # not a dataset: one line
    assert "no sessions found" in capsys.readouterr().err


def test_fit_on_too_few_sessions_says_so(dataset_root, tmp_path, capsys):
    for sid in ("user_1/session_4", "user_2/session_2", "user_6/session_1", "user_7/session_1"):
        shutil.copytree(dataset_root / sid, tmp_path / "data" / sid)
    rc = main(["fit", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--no-figures", "--no-cache"])
    err = capsys.readouterr().err
    assert rc == 2
    last = err.strip().splitlines()[-1]
    assert last.startswith("nao-trainer fit: error: 4 sessions") and "too few for K=3" in last
    assert last.endswith("or lower --k")  # core names the value k, the command its option
    assert "Traceback" not in err
    assert main(["fit", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--no-figures", "--no-cache",
                 "--k", "1"]) == 0
    assert artifacts.available_models(tmp_path / "out") == ["1"]


def test_figure_4_gets_the_per_sample_engagement_signal(dataset_root):
    from nao_trainer.learn.fit_source import engagement_signals

    signal_of = engagement_signals(dataset_root, "authors2018")
    series = signal_of("user_1/session_4")
    assert sorted(series) == list(range(1, 26))
    assert all(len(v) > 10 and 0 <= v.min() and v.max() <= 1 for v in series.values())
    assert signal_of("user_999/session_1") is None


def test_many_clusters_still_give_strict_json(dataset_root, tmp_path, tmp_path_factory, capsys):
    """K = 8 leaves one-session clusters (no cross-validation): null, never NaN, in the report and manifest."""
    out = tmp_path / "k8"
    rc = main(["fit", str(dataset_root), "--out", str(out), "--compat", "authors2018", "--json", "--k", "8",
               "--no-figures", "--cache", str(shared_cache(tmp_path_factory, "authors2018"))])
    assert rc == 0
    strict = dict(parse_constant=lambda name: pytest.fail(f"{name} is not JSON"))
    report = json.loads(capsys.readouterr().out, **strict)
    assert any(c["cv_rmse_performance"] is None for c in report["clusters"] if c["size"] == 1)
    json.loads((out / "manifest.json").read_text(), **strict)


def test_pyplot_without_matplotlib_is_a_user_error(monkeypatch):
    from nao_trainer.errors import UserError
    from nao_trainer.plots import pyplot

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    with pytest.raises(UserError, match=r"pip install 'nao-trainer\[plots\]'"):
        pyplot()


def test_fit_without_matplotlib_fails_before_reading(tmp_path, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else real(name, *a))
    rc = main(["fit", str(tmp_path / "missing"), "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "pip install 'nao-trainer[plots]'" in err and "--no-figures" in err


def test_fit_from_a_table_follows_its_provenance_sidecar(dataset_root, tmp_path_factory, tmp_path, capsys):
    table = tmp_path / "turns.csv"
    cache = shared_cache(tmp_path_factory, "authors2018")
    assert main(["import", str(dataset_root), "--out", str(table), "--compat", "authors2018", "--cache", str(cache),
                 "-q"]) == 0
    sidecar = tmp_path / "turns.csv.json"
    prov = json.loads(sidecar.read_text())
    prov["skipped"] = ["user_9/session_9: skipped: logfile not found"]
    sidecar.write_text(json.dumps(prov))
    capsys.readouterr()
    assert main(["fit", str(table), "--out", str(tmp_path / "m"), "--no-figures", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["compat"] == "authors2018" and report["skipped"] == prov["skipped"]
    manifest = json.loads((tmp_path / "m" / artifacts.MANIFEST).read_text())
    assert manifest["compat"] == "authors2018" and manifest["skipped"] == prov["skipped"]
    prov["compat"] = None  # a table imported without --compat cannot be fitted as authors2018
    sidecar.write_text(json.dumps(prov))
    assert main(["fit", str(table), "--out", str(tmp_path / "n"), "--no-figures", "--compat", "authors2018"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(sidecar) in err and "compat none" in err
    assert not (tmp_path / "n").exists()


def test_a_refit_writes_identical_files_and_the_shipped_policies_still_load(fitted, dataset_root, tmp_path_factory,
                                                                           tmp_path, monkeypatch):
    """Refitting as documented must not invalidate the shipped policies (issue: `make demo` exited 2)."""
    from nao_trainer.policies import learned

    _, out, _, _ = fitted
    again = tmp_path / "refit"
    assert main(["fit", str(dataset_root), "--out", str(again), "--compat", "authors2018", "--no-figures",
                 "--cache", str(shared_cache(tmp_path_factory, "authors2018"))]) == 0
    for name in ("manifest.json", "cluster_1.json", "cluster_2.json", "cluster_3.json"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name
    monkeypatch.setenv(artifacts.MODELS_ENV, str(again))
    for cluster in ("1", "2", "3"):
        for method in learned.METHODS:
            policy = learned.load_policy(f"usp:{cluster}:{method}", learning=False, state_path=None)
            policy.close()
    shipped = artifacts.load_simulator("2", artifacts.DEFAULT_MODELS_DIR)
    assert artifacts.load_simulator("2", again).fingerprint() == shipped.fingerprint()


def test_import_into_a_missing_folder_is_refused_and_creates_nothing(dataset_root, tmp_path, capsys):
    target = tmp_path / "nonexistent" / "dir" / "t.csv"
    assert main(["import", str(dataset_root), "--out", str(target), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"the folder {target.parent.parent} does not exist" in err
    assert not (tmp_path / "nonexistent").exists()


def test_the_table_of_a_cluster_of_one_session_prints_dashes_not_a_type_error():
    """Issue 17: `fit` with a cluster of one session ended in a TypeError (cli/fit.py, no CV for one session)."""
    from nao_trainer.cli.fit import format_table

    one = {"id": 1, "size": 1, "p": [1.0, 0.5, None, 0.25], "e": [0.1, 0.2, 0.3, 0.4], "rmse_performance": 0.1,
           "cv_rmse_performance": None, "rmse_engagement": 0.2, "cv_rmse_engagement": None}
    lines = format_table({"clusters": [one]}).splitlines()
    assert len(lines) == 2 and lines[1].split()[:2] == ["1", "1"] and lines[1].count(" -") >= 3


def test_fit_filters_by_study_and_input_and_refuses_simulated_participants_silently(tmp_path, capsys):
    from nao_trainer.data.turn_table import COLUMNS, TurnTable, write_table

    rows = []
    for k, (study, kind) in enumerate((("paper", "tactile"), ("paper", "simulated"), ("demo", "simulated"))):
        for turn in range(1, 4):
            row = {c: (0.5 if t is float else (0 if t is int else "")) for c, t in COLUMNS.items()}
            row.update(session=f"S{k}", pseudonym=f"P{k}", study=study, input=kind, turn=turn, state=4 + 27,
                       length=5, level=2, sequence="ABCAB", response="ABCAB", success=1, score=2, signed_score=2)
            rows.append(row)
    table = tmp_path / "t.csv"
    write_table(TurnTable.from_rows(rows), table, {"compat": None})
    assert main(["fit", str(table), "--out", str(tmp_path / "m"), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "2 of 3 sessions had a simulated participant" in err and "--exclude-simulated" in err
    assert "sessions by study/input: demo/simulated 1, paper/simulated 1, paper/tactile 1" in err
    assert "--include-simulated" in err and err.count("error:") == 1
    main(["fit", str(table), "--out", str(tmp_path / "m"), "--no-figures", "--exclude-simulated"])
    err = capsys.readouterr().err
    assert "S1: left out by the filter (study 'paper', input 'simulated')" in err and "simulated participant" not in err
    main(["fit", str(table), "--out", str(tmp_path / "m"), "--no-figures", "--study", "demo"])
    err = capsys.readouterr().err
    assert "S0: left out by the filter" in err and "1 of 1 sessions had a simulated participant" in err
