"""Sweeps (experiments.sweep, `nao-trainer sweep`) and the fan-out to local processes or a dask cluster (learn.parallel)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from nao_trainer.cli import main
from nao_trainer.errors import ConfigError
from nao_trainer.experiments import sweep
from nao_trainer.learn import parallel
from nao_trainer.learn.training import TrainingSpec, train_grid
from nao_trainer.learn.users import cluster_user_set


@pytest.mark.parametrize("param, message", [
    ("beta1=5:1:3", "empty range"),
    ("beta1=0:1:0", "empty range"),
    ("beta1=0:1:-2", "negative count"),
    ("epsilon=0:1:3", "unknown parameter 'epsilon'"),
    ("beta1=", "use NAME=START:STOP:COUNT"),
    ("beta1=a:b:c", "values must be numbers"),
    ("beta1=0:10", "the COUNT is missing"),
    ("alpha=0:1:3", "not a valid setting"),
])
def test_bad_sweep_specifications_are_refused_before_any_work(param, message, monkeypatch, capsys, tmp_path):
    def no_work(*args, **kwargs):
        raise AssertionError("work started")

    monkeypatch.setattr(sweep, "fan_out", no_work)  # the module's own name: a patch of learn.parallel would leak into modules first imported meanwhile
    monkeypatch.setattr(sweep, "run", no_work)
    assert main(["sweep", "--param", param, "--out", str(tmp_path / "s"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err
    assert not (tmp_path / "s").exists()


def test_the_method_follows_the_swept_weight():
    assert sweep.make_spec(["beta1=0:10:3"]).method == "shaping"
    assert sweep.make_spec(["beta2=0,0.8"]).method == "qaug"
    assert sweep.make_spec(["alpha=0.05,0.1"]).method == "performance"
    assert len(sweep.make_spec(["alpha=0.05,0.1", "gamma=0.9:0.95:3"]).points()) == 6
    with pytest.raises(ConfigError, match="each parameter once"):
        sweep.make_spec(["alpha=0.1", "alpha=0.2"])


def test_sweep_command_writes_its_table_and_figure(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["sweep", "--param", "beta1=0:7.5:2", "--seeds", "2", "--episodes", "200", "--out", str(out),
                 "--json"]) == 0
    said = capsys.readouterr()
    report = json.loads(said.out)
    assert len(report["results"]) == 2 * 3 and report["method"] == "shaping"
    assert "sweep: (point, user) runs: 6/6 done" in said.err, said.err  # issue 29: long commands say their progress
    assert {r["beta1"] for r in report["results"]} == {0.0, 7.5}
    assert (out / "sweep.csv").read_text().count("\n") == 7 and (out / "sweep.png").stat().st_size > 0


def test_a_sweep_over_two_parameters_draws_a_grid_and_over_three_says_why_not(tmp_path, capsys):
    """Issue 17: two parameters wrote no figure and said nothing (the docs list sweep.png)."""
    out = tmp_path / "s2"
    assert main(["sweep", "--param", "alpha=0.1,0.2", "--param", "gamma=0.9,0.95", "--seeds", "1", "--episodes",
                 "50", "--out", str(out), "--json"]) == 0
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    out = tmp_path / "s3"
    assert main(["sweep", "--param", "alpha=0.1", "--param", "gamma=0.9", "--param", "beta1=1", "--seeds", "1",
                 "--episodes", "50", "--out", str(out), "--json"]) == 0
    assert not (out / "sweep.png").exists() and "no sweep.png for 3 swept parameters" in capsys.readouterr().err


def test_dask_cluster_gives_bit_identical_results_to_local_processes():
    distributed = pytest.importorskip("distributed")
    spec = sweep.make_spec(["beta2=0,0.8"], seeds=2, episodes=150)
    users = cluster_user_set(None)[:2]
    local = sweep.run(spec, users, workers=1)
    grid_spec = TrainingSpec(seeds=2, episodes=100, workers=2)
    sims, ids = [u.train for u in users], [u.cluster for u in users]
    grid_local = train_grid(sims, ids, grid_spec, progress=False)
    with distributed.LocalCluster(host="127.0.0.1", n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address="127.0.0.1:0") as cluster:  # loopback, any free port
        address = cluster.scheduler_address.removeprefix("tcp://")
        remote = sweep.run(spec, users, backend=f"dask://{address}")
        grid_remote = train_grid(sims, ids, replace(grid_spec, backend=f"dask://{address}"), progress=False)
    assert remote == local  # floats compared exactly
    for key in ("q", "h", "h_counts", "visits", "episode_score", "episode_engagement"):
        assert np.array_equal(getattr(grid_remote, key), getattr(grid_local, key)), key


def test_an_unreachable_scheduler_is_an_error_within_the_deadline(monkeypatch, capsys, tmp_path):
    pytest.importorskip("distributed")
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 2.0)
    rc = main(["sweep", "--param", "beta1=0,1", "--seeds", "1", "--episodes", "10", "--backend", "dask://127.0.0.1:9",
               "--out", str(tmp_path / "s"), "--no-plots"])  # ended by its deadline: the message names it
    err = capsys.readouterr().err
    assert rc == 2 and "no dask scheduler answered within 2 s" in err and "Traceback" not in err


def test_backend_text_is_checked():
    with pytest.raises(ConfigError, match="dask://HOST:PORT"):
        parallel.check_backend("ray://x")
    assert parallel.check_backend("dask://10.0.0.2:8786") == "tcp://10.0.0.2:8786"
    assert parallel.check_backend(None) is None
