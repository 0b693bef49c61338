"""Grid training: reproducibility, summaries, outputs and `nao-trainer train --json`."""
from __future__ import annotations

import time

import csv
import gzip
import json

import numpy as np
import pytest

from nao_trainer.learn import artifacts

from nao_trainer.learn import policy_files
from nao_trainer.cli import main
from nao_trainer.core import mdp
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.learn.training import TrainingSpec, mean_ci, train_grid, write_outputs


def simulators():
    return [
        UserSimulator.from_level_rates("cluster-1", [0.95, 0.8, 0.35, 0.06], [0.3, 0.4, 0.5, 0.6]),
        UserSimulator.from_level_rates("cluster-2", [0.99, 0.95, 0.65, 0.3], [0.6, 0.5, 0.4, 0.3]),
    ]


@pytest.fixture(scope="module")
def models_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("models")
    artifacts.save_models(folder, simulators(), [{"id": 1}, {"id": 2}], {"k": 2})
    return folder


SMALL = dict(seeds=3, episodes=40, turns=25, workers=1)


@pytest.fixture(scope="module")
def small_run():
    return train_grid(simulators(), ["1", "2"], TrainingSpec(**SMALL), progress=False)


def test_grid_shapes_and_summary(small_run):
    r = small_run
    assert r.episode_score.shape == (2, 3, 3, 40) and r.q.shape == (2, 3, 3, mdp.N_STATES, mdp.N_ACTIONS)
    assert r.turns == 2 * 3 * 3 * 40 * 25
    rows = r.results()
    methods = ("performance", "shaping", "qaug")
    assert [(x["cluster"], x["method"]) for x in rows] == [(c, m) for c in "12" for m in methods]
    tail = r.episode_score[0, 1, :, -4:].mean(axis=1)  # last 10 % of 40 episodes
    assert rows[1]["score_mean"] == pytest.approx(tail.mean())
    lo, hi = rows[1]["score_ci"]
    assert lo <= rows[1]["score_mean"] <= hi
    for row in rows:
        assert sum(row["s0_probabilities"].values()) == pytest.approx(1, abs=1e-5)
        assert row["random_score"] < row["optimal_score"]
    assert (r.visits[:, :, :, mdp.START] == 40).all()


def test_diff_ci_is_a_welch_interval(small_run):
    from nao_trainer.learn.training import diff_ci

    out = diff_ci(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 3.0]))
    # se^2 = 1/3 + 3/3; Welch dof = (4/3)^2 / ((1/3)^2/2 + 1/2) = 3.2
    half = 3.072829 * np.sqrt(4 / 3)  # t_0.975 at 3.2 degrees of freedom
    assert out["diff"] == 1.0 and out["ci"] == pytest.approx([1 - half, 1 + half], rel=1e-4)
    assert out["significant"] is False
    assert diff_ci(np.array([5.0, 5.1, 4.9]), np.array([1.0, 1.1, 0.9]))["significant"] is True
    rows = small_run.results()
    assert "vs_performance" not in rows[0] and rows[1]["vs_performance"]["score_diff"]["diff"] == pytest.approx(
        rows[1]["score_mean"] - rows[0]["score_mean"])


def test_mean_ci_is_a_t_interval():
    mean, (lo, hi) = mean_ci(np.array([1.0, 2.0, 3.0]))
    assert mean == 2.0 and hi - mean == pytest.approx(4.302653 * 1.0 / np.sqrt(3), rel=1e-5)
    assert mean_ci(np.array([5.0])) == (5.0, None)


def test_same_seed_identical_other_seed_different(small_run, tmp_path):
    again = train_grid(simulators(), ["1", "2"], TrainingSpec(**SMALL), progress=False)
    assert np.array_equal(small_run.q, again.q) and np.array_equal(small_run.episode_score, again.episode_score)
    write_outputs(small_run, tmp_path / "a", "m", "c")
    write_outputs(again, tmp_path / "b", "m", "c")
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert len(files) == 2 * 3 + 4
    for name in files:
        if name != "results.json":  # holds the run time
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    other = train_grid(simulators(), ["1", "2"], TrainingSpec(**{**SMALL, "seed": 1}), progress=False)
    assert not np.array_equal(small_run.episode_score, other.episode_score)


def test_agent_results_do_not_depend_on_the_rest_of_the_grid_or_workers(small_run):
    # Only shaping, only cluster 2, split over two worker processes: same numbers as in the full grid.
    part = train_grid(simulators()[1:], ["2"], TrainingSpec(**{**SMALL, "methods": ("shaping",), "workers": 2}),
                      progress=False)
    assert np.array_equal(part.q[0, 0], small_run.q[1, 1])
    assert np.array_equal(part.episode_engagement[0, 0], small_run.episode_engagement[1, 1])


def test_spec_validation():
    with pytest.raises(ValueError, match="method must be one of"):
        TrainingSpec(methods=("sarsa",))
    with pytest.raises(ValueError, match="episodes must be an integer >= 1, got 0"):
        TrainingSpec(episodes=0)


def test_write_outputs(small_run, tmp_path):
    from nao_trainer.plots.learning import write_figures

    paths = write_outputs(small_run, tmp_path, "test-models", "nao-trainer train (test)")
    paths.update(write_figures(small_run, tmp_path))
    for key in ("curves", "s0", "results", "figure7", "figure8"):
        assert paths[key].exists() and paths[key].stat().st_size > 0
    assert paths["figure7"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with gzip.open(paths["curves"], "rt") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 * 3 * 40
    first = rows[0]
    scores = small_run.episode_score[0, 0, :, 0]
    assert float(first["score_mean"]) == pytest.approx(scores.mean(), rel=1e-4)
    assert float(first["score_lo"]) <= float(first["score_mean"]) <= float(first["score_hi"])
    with open(paths["s0"]) as fh:
        s0 = list(csv.DictReader(fh))
    s0_visits = small_run.visits[0, 0, :, mdp.encode(*mdp.S0)].mean()
    assert float(s0[0]["s0_visits_mean"]) == pytest.approx(s0_visits, abs=0.05)
    summary = json.loads(paths["results"].read_text())
    assert set(summary["default_method"]) == {"1", "2"}
    manifest = policy_files.read_manifest(tmp_path)
    for name in manifest["files"].values():
        payload = policy_files.read_policy_file(tmp_path / name)
        assert payload["simulator"]["fingerprint"] in {s.fingerprint() for s in simulators()}
    # The shipped file is the representative seed's learner.
    k = small_run.representative_seed(1, 2)
    payload = policy_files.read_policy_file(tmp_path / policy_files.policy_filename("2", "qaug"))
    assert np.array_equal(np.array(payload["q"]), small_run.q[1, 2, k])
    assert payload["training"]["seed_index"] == k


def test_cli_train_json(models_dir, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["train", "--models", str(models_dir), "--seeds", "2", "--episodes", "20", "--workers", "1",
                 "--methods", "performance,qaug", "--out", str(out), "--no-plots", "--json"])
    assert code == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert set(data) == {"results", "turns", "seconds"}
    assert data["turns"] == 2 * 2 * 2 * 20 * 25
    row = data["results"][0]
    for key in ("cluster", "method", "score_mean", "score_ci", "engagement_mean", "engagement_ci"):
        assert key in row
    assert [r["method"] for r in data["results"]] == ["performance", "qaug"] * 2
    assert "train:" in captured.err  # progress on stderr
    assert (out / "usp_1_qaug.json").exists() and not (out / "usp_1_shaping.json").exists()


def test_cli_train_errors_are_one_line(models_dir, tmp_path, capsys):
    assert main(["train", "--models", str(models_dir), "--methods", "performance,sarsa", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown method 'sarsa'" in err
    assert main(["train", "--models", str(tmp_path / "nowhere"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "no user models here" in err and "nao-trainer fit" in err
    assert main(["train", "--models", str(models_dir), "--episodes", "0", "--out", str(tmp_path)]) == 2
    assert "episodes must be an integer >= 1" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("")
    assert main(["train", "--models", str(models_dir), "--out", str(tmp_path / "a_file")]) == 2
    captured = capsys.readouterr()
    assert "a_file: cannot create the output folder" in captured.err and "agents" not in captured.err  # nothing ran


def test_cli_train_option_errors_name_the_option_once(models_dir, tmp_path, capsys):
    assert main(["train", "--models", str(models_dir), "--methods", "performance,sarsa", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nao-trainer train: error: --methods: unknown method 'sarsa' (each method must be one of ")
    assert "::" not in err and err.count("--methods") == 1  # was "--methods:: methods: ..."
    assert main(["train", "--models", str(models_dir), "--methods", ",", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()  # was "--methods:: methods: give at least one of ..."
    assert err == "nao-trainer train: error: --methods: give at least one of performance, shaping, qaug"
    assert main(["train", "--models", str(models_dir), "--seeds", "0", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == "nao-trainer train: error: --seeds must be an integer >= 1, got 0"


def test_cli_train_records_the_arguments_it_was_given(models_dir, tmp_path, monkeypatch):
    import sys

    monkeypatch.setattr(sys, "argv", ["pytest", "-q", "somewhere"])  # not what main() parsed
    out = tmp_path / "out"
    argv = ["train", "--models", str(models_dir), "--seeds", "1", "--episodes", "5", "--workers", "1",
            "--methods", "qaug", "--out", str(out), "--no-plots", "--json"]
    assert main(argv) == 0
    command = json.loads((out / "results.json").read_text())["spec"]["command"]
    assert command == "nao-trainer " + " ".join(argv)


def test_help_and_version_do_not_import_numpy():
    import subprocess
    import sys

    for flag in ("--help", "--version"):
        code = (f"import sys; from nao_trainer.cli import main\ntry: main([{flag!r}])\nexcept SystemExit: pass\n"
                "print('numpy' in sys.modules)")
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert done.stdout.strip().splitlines()[-1] == "False", (flag, done.stdout, done.stderr)


def test_cli_method_names_match_the_learner():
    from nao_trainer.cli import train
    from nao_trainer.core.qlearning import METHODS

    assert train.METHODS == METHODS


def test_figure_labels_show_the_runs_weights():
    from nao_trainer.core.qlearning import QConfig
    from nao_trainer.plots.learning import method_label

    config = QConfig(beta1=3.0, beta2=0.25)
    assert method_label("shaping", config) == "reward shaping (r + 3e)"
    assert method_label("qaug", config) == "Q-augmentation (Q + 0.25H)"
    assert method_label("qaug", QConfig()) == "Q-augmentation (Q + 0.8H)"
    assert method_label("performance", config) == "performance (r)"


def test_learning_curves_are_gzip_level_6(small_run, tmp_path):
    from nao_trainer.learn.training import write_curves_csv

    path = tmp_path / "curves.csv.gz"
    write_curves_csv(small_run, path)
    assert path.read_bytes()[8] == 0  # gzip XFL: 2 = level 9 (the old default), 4 = level 1, 0 = others
    assert gzip.decompress(path.read_bytes()).startswith(b"cluster,method,episode,")


def test_an_interrupted_or_failed_train_leaves_no_empty_folder(models_dir, tmp_path, capsys):
    import signal
    import subprocess
    import sys
    import time

    assert main(["train", "--models", str(tmp_path / "nowhere"), "--out", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()
    for after in (0.0, 0.5):  # at once (models loading, the kernel compiling) and in the training loop
        out = tmp_path / f"interrupted-{after}"
        proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "train", "--models", str(models_dir), "--seeds",
                                 "4", "--episodes", "1000000", "--workers", "1", "--out", str(out), "--no-plots"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)
        time.sleep(after)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert "Traceback" not in err and not out.exists()


def test_a_ctrl_c_just_after_the_folder_is_made_leaves_none(models_dir, tmp_path, monkeypatch):
    """The window the loaded machine found: Ctrl-C handled on the first bytecode after mkdir."""
    from nao_trainer.cli import _checks, train as train_cli

    made = _checks.make_output_dir

    def then_ctrl_c(path):
        made(path)
        raise KeyboardInterrupt

    monkeypatch.setattr(train_cli, "make_output_dir", then_ctrl_c)
    out = tmp_path / "new"
    assert main(["train", "--models", str(models_dir), "--seeds", "1", "--episodes", "10", "--out", str(out),
                 "--no-plots"]) == 130
    assert not out.exists()


def test_a_ctrl_c_that_a_library_swallowed_is_raised_again():
    """numpy's C loops (np.char.mod) and numpy.random's import swallowed a KeyboardInterrupt: `train` went on."""
    import os
    import signal

    from nao_trainer import cli
    from nao_trainer.errors import raise_if_interrupted

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("Python's own Ctrl-C handler is not in place in this process")
    with cli._ctrl_c_noted():
        raise_if_interrupted()  # none yet
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)  # the handler runs in this thread before the sleep ends
        except KeyboardInterrupt:
            pass  # what the library did
        with pytest.raises(KeyboardInterrupt):
            raise_if_interrupted()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with cli._ctrl_c_noted():  # the next command starts without it
        raise_if_interrupted()
