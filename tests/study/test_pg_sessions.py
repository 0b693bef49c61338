"""Sessions on a PostgreSQL registry (issue 31): `study next` on a site's laptop (the configuration from the
registry, not the arm), the session recorded once under its key, a network that goes mid-session (the
session finishes locally, `study record` or the next `study next` records it once), a killed `study next`,
withdrawals, and the statistician's `study analyse` and `study export --bids`. A real server (conftest
``pg_cluster``); a site's network path is a relay the test can cut (tests/_pg_cluster.py ``Relay``)."""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import uuid
from collections import Counter
from pathlib import Path

import pytest

from nao_trainer.cli import main
from nao_trainer.study import pg

ROOT = Path(__file__).resolve().parents[2]
BASE = """\
study: {name: pgs}
robot: {url: mock}
session: {turns: 3, practice: false}
timing: {speed: 50}
answers: {input: simulated}
eeg: {mode: "off", xdf: false}
"""
PROTOCOL = """\
protocol: {name: pg-3arm, description: personalised vs level 2 vs random difficulty}
study_config: base.yaml
arms:
  - {name: personalised, policy: personalised}
  - {name: level2, policy: schedule, overrides: {policy.schedule: [L2]}}
  - {name: random, policy: random}
sessions: {per_participant: 2, interval_days: {min: 0, max: 7}}
target_n: 12
allocation: {method: blocked, block_size: 6}
blinding: true
outcomes: {primary: score, secondary: [success_rate]}
analysis: {model: "outcome ~ arm + session + (1|participant)", reference_arm: level2}
"""
ARMS = ("personalised", "level2", "random", "schedule")


def cli(capsys, *args) -> tuple[int, str, str]:
    code = main(["study", *map(str, args)])
    out = capsys.readouterr()
    assert "Traceback" not in out.err, out.err
    return code, out.out, out.err


class Trial:
    """A study on the server: the administrator's folder, a folder per site (a copy: protocol.yaml and
    registry.url) and the statistician's; the roles' passwords in a PGPASSFILE outside every folder."""

    def __init__(self, cluster, tmp_path: Path, monkeypatch, capsys):
        self.tmp, self.cluster, self.db = tmp_path, cluster, "p_" + uuid.uuid4().hex[:10]
        self.passfile = tmp_path / "secrets" / "pgpass"
        self.passfile.parent.mkdir()
        self.lines = [f"*:*:*:postgres:{cluster.password}"]
        self._write()
        monkeypatch.setenv("PGPASSFILE", str(self.passfile))
        monkeypatch.delenv("PGPASSWORD", raising=False)
        monkeypatch.setenv("PGUSER", "postgres")
        self.monkeypatch = monkeypatch
        with pg.connect(cluster.url(), autocommit=True) as c:
            c.execute(f"CREATE DATABASE {self.db}")
        (tmp_path / "base.yaml").write_text(BASE)
        (tmp_path / "protocol.yaml").write_text(PROTOCOL)
        self.admin = tmp_path / "admin"
        code, out, err = cli(capsys, "init", tmp_path / "protocol.yaml", "--out", self.admin, "--registry",
                             cluster.url(self.db))
        assert code == 0, err
        self.roles = {}
        for what, name in (("site", "north"), ("site", "south"), ("statistician", "stats")):
            code, out, err = cli(capsys, what, "add", self.admin, name)
            assert code == 0, err
            self.roles[name] = out.split("role ")[1].split(";")[0]
            self.lines.append(f"*:*:*:{self.roles[name]}:{out.strip().rsplit(' ', 1)[1]}")
        self._write()
        self.folders = {name: self.copy(name) for name in self.roles}

    def _write(self):
        self.passfile.write_text("\n".join(self.lines) + "\n")
        self.passfile.chmod(0o600)

    def copy(self, name: str) -> Path:
        folder = self.tmp / name
        folder.mkdir()
        for f in ("protocol.yaml", "registry.url"):
            shutil.copy(self.admin / f, folder / f)
        return folder

    def as_(self, name: str) -> Path:
        self.monkeypatch.setenv("PGUSER", self.roles[name])
        return self.folders[name]

    def sql(self, query: str, params: tuple = ()) -> list[tuple]:
        with pg.connect(self.cluster.url(self.db), autocommit=True) as c:
            return c.execute(query, params).fetchall()


@pytest.fixture
def trial(pg_cluster, tmp_path, monkeypatch, capsys):
    return Trial(pg_cluster, tmp_path, monkeypatch, capsys)


def _env(role: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "QI_LOG_LEVEL": "silent", "PGUSER": role}


def _next_proc(folder: Path, pseudonym: str, role: str, model: str = "1") -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(folder), pseudonym,
                             "--no-keys", "--user-model", model], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(role))


def test_study_next_on_a_site_laptop_gets_the_configuration_not_the_arm(trial, capsys):
    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    proc = _next_proc(north, "P001", trial.roles["north"])
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 0, err
    assert "P001, session 1 of 2, arm (blinded)" in err
    assert not any(w in (out + err).lower() for w in ARMS)
    rows = trial.sql("SELECT key, number, folder, status, files, entry FROM sessions")
    assert len(rows) == 1
    key, number, folder, status, files, entry = rows[0]
    assert (number, status) == (1, "completed") and (north / "sessions" / folder / "session.json").is_file()
    from nao_trainer.study.registry import file_sha256

    assert files and all(file_sha256(north / "sessions" / folder / f) == h for f, h in files.items())
    assert entry["host"] and entry["ended"] and entry["key"] == key
    assert not list((north / "outbox").glob("*.json"))  # taken by the registry: nothing kept
    # a site cannot run another site's participant; the statistician cannot run sessions
    south = trial.as_("south")
    shutil.copytree(north / "sessions", south / "sessions")
    code, _, err = cli(capsys, "next", south, "P001", "--no-keys")
    assert code == 2 and "not a participant of your site" in err and len(err.strip().splitlines()) == 1
    stats = trial.as_("stats")
    code, _, err = cli(capsys, "next", stats, "P001", "--no-keys")
    assert code == 2 and "a site's role" in err and len(err.strip().splitlines()) == 1


def test_network_lost_mid_session_finishes_locally_and_is_recorded_once(trial, capsys, tmp_path):
    """The relay is cut while the session plays its first turn: the session finishes, its entry stays in the
    outbox (one line says so); with the network back `study record` records it once, a second time nothing;
    the next `study next` of the participant is session 2."""
    from tests._pg_cluster import Relay

    from nao_trainer.session.wiring import RunOptions
    from nao_trainer.study import remote

    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    relay = Relay(trial.cluster, Path(f"/tmp/nt-relay-{uuid.uuid4().hex[:8]}")).start()
    try:
        (north / "registry.url").write_text(relay.url(trial.db) + "\n")

        class CutOnFirstTurn(io.StringIO):
            def write(self, text):
                if text.lstrip().startswith("turn ") and relay._server is not None:
                    relay.cut()
                return super().write(text)

        progress = CutOnFirstTurn()
        plan, result = remote.run_next(north, "P001", {"participant_model.user_model": "1"},
                                       RunOptions(keys=False, quiet=False), progress=progress)
        shown = progress.getvalue()
        assert result.status == "completed" and "the registry cannot be reached" in shown
        assert f"`nao-trainer study record {north}`" in shown
        kept = json.loads((north / "outbox" / f"{plan.key}.json").read_text())
        assert kept["status"] == "completed" and kept["folder"] == result.path.name
        assert trial.sql("SELECT status FROM sessions") == [("running",)]  # what the server got before the cut
        code, _, err = cli(capsys, "record", north)
        assert code == 2 and "cannot reach the registry server" in err and len(err.strip().splitlines()) == 1
        relay.restore()
        code, out, _ = cli(capsys, "status", north)
        assert code == 0 and "not yet in the registry: 1 session entry" in out
        code, out, _ = cli(capsys, "record", north)
        assert code == 0 and "1 session(s) recorded" in out and "recorded as completed" in out
        code, out, _ = cli(capsys, "record", north)  # again: nothing left, nothing recorded twice
        assert code == 0 and "0 session(s) recorded" in out
        assert trial.sql("SELECT key, number, status, folder FROM sessions") == \
            [(plan.key, 1, "completed", result.path.name)]
        assert not list((north / "outbox").glob("*.json"))
    finally:
        relay.cut()
        shutil.rmtree(relay.folder, ignore_errors=True)


def test_a_killed_study_next_is_recorded_by_the_next_one_never_twice(trial, capsys):
    """SIGKILL of `study next` while its session runs (the server has it as running): the next `study next`
    of the participant records the killed one from the outbox (as its folder says) and runs the next session;
    `study record` afterwards finds nothing; no session number counts twice."""
    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    proc = _next_proc(north, "P001", trial.roles["north"])
    while not trial.sql("SELECT 1 FROM sessions WHERE status = 'running'") and proc.poll() is None:
        threading_wait(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    killed = json.loads(next((north / "outbox").glob("*.json")).read_text())
    assert killed["status"] == "running"
    again = _next_proc(north, "P001", trial.roles["north"])
    out, err = again.communicate(timeout=240)
    assert again.returncode == 0, err
    assert "P001's session 1 (" in err and "from outbox/" in err  # the killed one, recorded first
    code, out, _ = cli(capsys, "record", north)
    assert code == 0 and "0 session(s) recorded" in out
    rows = trial.sql("SELECT key, number, status FROM sessions ORDER BY recorded")
    assert rows[0][0] == killed["key"] and rows[0][2] in ("completed", "interrupted")
    assert len(rows) == 2 and rows[1][2] == "completed" and rows[1][1] == (2 if rows[0][2] == "completed" else 1)
    assert not list((north / "outbox").glob("*.json"))


def threading_wait(seconds: float) -> None:
    import threading

    threading.Event().wait(seconds)


ABILITIES = ("sim/participants/level2.json", "sim/participants/level4.json", "1", "3")


@pytest.mark.slow
def test_two_sites_on_postgresql_from_enrolment_to_a_validated_bids_export(trial, capsys, tmp_path):
    """Issue 31's Done-when on PostgreSQL: two sites, 12 participants enrolled from two processes at once as
    the two sites (one concealed sequence: balanced), 24 sessions through `study next` on the sites' laptops,
    `study status` per role, `study analyse` (the statistician; refused to a site) and a BIDS export of the
    sites' session folders that the official validator accepts."""
    from tests.study.test_study_end_to_end import validator

    loop = ("import sys\nfrom nao_trainer.cli import main\nfor _ in range(6):\n"
            "    assert main(['study', 'enrol', sys.argv[1], '--consent-date', '2026-11-20', "
            "'--consent-version', '2.1']) == 0\n")
    shells = {s: subprocess.Popen([sys.executable, "-c", loop, str(trial.folders[s])], env=_env(trial.roles[s]),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for s in ("north", "south")}
    people: dict[str, list[str]] = {}
    for site, proc in shells.items():
        out, err = proc.communicate(timeout=240)
        assert proc.returncode == 0, err
        people[site] = [line.split(":")[0] for line in out.splitlines() if "enrolled (arm concealed" in line]
    assert sorted(len(v) for v in people.values()) == [6, 6]
    everyone = sorted(people["north"] + people["south"])
    assert len(set(everyone)) == 12  # each site's pseudonyms from its own range
    assert sorted(people["north"]) == [f"P{i:03d}" for i in range(1, 7)]
    assert sorted(people["south"]) == [f"P{i:03d}" for i in range(101, 107)]
    site_of = {p: s for s, ps in people.items() for p in ps}
    outputs = []
    for session in (1, 2):
        for batch in range(0, 12, 6):  # six sessions side by side (three per site)
            procs = [(p, _next_proc(trial.folders[site_of[p]], p, trial.roles[site_of[p]],
                                    ABILITIES[everyone.index(p) % len(ABILITIES)]))
                     for p in (people["north"][batch // 2:batch // 2 + 3] + people["south"][batch // 2:batch // 2 + 3])]
            for p, proc in procs:
                out, err = proc.communicate(timeout=240)
                assert proc.returncode == 0, f"study next {p} session {session}: {err[-3000:]}"
                assert f"{p}, session {session} of 2, arm (blinded)" in err
                outputs.append(out + err)
    assert not any(w in text.lower() for text in outputs for w in ARMS + ("assessment", "posterior"))
    code, _, err = cli(capsys, "next", trial.as_("north"), people["north"][0], "--no-keys")
    assert code == 2 and "completed all 2 sessions" in err

    code, out, _ = cli(capsys, "status", trial.as_("south"))  # a site: its own participants, no arm
    assert code == 0 and "6 participant(s)" in out and out.count("sessions 2") == 6
    assert not any(a in out.split("\n", 2)[2] for a in ARMS)
    code, _, err = cli(capsys, "analyse", trial.folders["south"])
    assert code == 2 and "the statistician's role only" in err and len(err.strip().splitlines()) == 1
    stats = trial.as_("stats")
    code, out, _ = cli(capsys, "status", stats)
    assert code == 0 and "north: 6 participant(s), 12 session(s)" in out and "south: 6 participant(s), 12 session(s)" in out
    for site in ("north", "south"):  # the statistician gathers the sites' session folders
        shutil.copytree(trial.folders[site] / "sessions", stats / "sessions", dirs_exist_ok=True)
    code, _, err = cli(capsys, "analyse", stats)
    assert code == 2 and "study unblind" in err  # blinded: unblind first, as on one laptop
    code, out, _ = cli(capsys, "unblind", stats, "--reason", "final analysis")
    assert code == 0
    arms = dict(line.split("\t") for line in out.splitlines() if "\t" in line)
    assert sorted(Counter(arms.values()).values()) == [4, 4, 4]
    code, out, err = cli(capsys, "analyse", stats)
    assert code == 0, err
    assert "PRIMARY" in out and load_sha(trial) in out
    import csv

    with open(stats / "analysis" / "estimates.csv", newline="") as fh:
        primary = {r["term"]: r for r in csv.DictReader(fh) if r["role"] == "primary"}
    assert {"arm[personalised]", "arm[random]", "session"} <= set(primary)
    assert all(r["n_sessions"] == "24" for r in primary.values())
    bids = tmp_path / "bids"
    code, out, err = cli(capsys, "export", stats, "--bids", bids)
    assert code == 0, err
    assert "12 participants, 24 sessions of behaviour, 0 with EEG" in out
    with open(bids / "participants.tsv", newline="") as fh:
        table = {r["participant_id"]: r["arm"] for r in csv.DictReader(fh, delimiter="\t")}
    assert table == {f"sub-{p}": a for p, a in arms.items()}
    log = trial.sql("SELECT reason FROM unblindings ORDER BY id")  # every reading of the arms is logged
    assert [r[0] for r in log] == ["final analysis", "study analyse: the arms read for it",
                                   "study export: the arms read for it"]
    tool = validator()
    if tool is None:
        pytest.skip("the BIDS validator is not installed (.ci/run installs it with npm into .tools/)")
    res = subprocess.run([str(tool), str(bids), "--json"], capture_output=True, text=True, timeout=300)
    errors = json.loads(res.stdout)["issues"]["errors"]
    assert not errors, [(e["key"], e.get("reason")) for e in errors]


def load_sha(trial) -> str:
    from nao_trainer.study.protocol import protocol_hash

    return protocol_hash((trial.admin / "protocol.yaml").read_text())


def test_withdraw_refusals_and_the_statisticians_checks_on_postgresql(trial, capsys):
    """`study withdraw` at the participant's site (recorded in the registry; --data delete removes the
    laptop's folders; no further session); the statistician's export refuses a session folder not copied
    or altered, in one line; a site's role is refused the export and the amendment, and --resume of a
    session that completed."""
    north = trial.as_("north")
    for _ in range(2):
        assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    proc = _next_proc(north, "P001", trial.roles["north"])
    assert proc.communicate(timeout=240) and proc.returncode == 0
    folder = trial.sql("SELECT folder FROM sessions")[0][0]

    def one_line(code, err, text):
        assert code == 2 and text in err and len(err.strip().splitlines()) == 1, err

    code, _, err = cli(capsys, "export", north, "--bids", trial.tmp / "x")
    one_line(code, err, "the statistician's role only")
    code, _, err = cli(capsys, "amend", north, trial.tmp / "protocol.yaml", "--reason", "r")
    one_line(code, err, "study amend: the study's administrator only")
    code, _, err = cli(capsys, "next", north, "P001", "--resume", "--no-keys")
    one_line(code, err, "P001: no interrupted session to resume")
    code, _, err = cli(capsys, "withdraw", trial.as_("south"), "P001", "--data", "keep")
    one_line(code, err, "not a participant of your site")

    stats = trial.as_("stats")
    assert cli(capsys, "unblind", stats, "--reason", "data check")[0] == 0
    code, _, err = cli(capsys, "export", stats, "--bids", trial.tmp / "bids")
    one_line(code, err, "copy every site's sessions/ folder into it")
    shutil.copytree(north / "sessions", stats / "sessions")
    turns = stats / "sessions" / folder / "turns.csv"
    turns.write_text(turns.read_text() + "\n")
    code, _, err = cli(capsys, "export", stats, "--bids", trial.tmp / "bids")
    one_line(code, err, "differs from the checksum its site recorded")

    north = trial.as_("north")
    code, out, err = cli(capsys, "withdraw", north, "P001", "--data", "delete", "--reason", "moved away")
    assert code == 0 and "withdrawal recorded in the registry" in out, err
    assert not (north / "sessions" / folder).exists() and (stats / "sessions" / folder).exists()
    withdrawn = trial.sql("SELECT withdrawn FROM participants WHERE pseudonym = 'P001'")[0][0]
    assert withdrawn["data"] == "delete" and withdrawn["reason"] == "moved away"
    code, _, err = cli(capsys, "next", north, "P001", "--no-keys")
    one_line(code, err, "P001: withdrew on")
    assert cli(capsys, "withdraw", north, "P002", "--data", "keep")[0] == 0
    code, _, err = cli(capsys, "withdraw", north, "P002", "--data", "keep")
    one_line(code, err, "P002: already withdrawn")
    code, out, _ = cli(capsys, "status", north)
    assert out.count("WITHDRAWN") == 2
    stats = trial.as_("stats")  # P001's data deleted: left out (its altered copy is not read)
    code, out, err = cli(capsys, "export", stats, "--bids", trial.tmp / "bids")
    assert code == 0 and "1 participants, 0 sessions" in out, err


@pytest.mark.slow
def test_killed_study_next_and_record_leave_the_registry_whole(pg_cluster, tmp_path):
    """One round of issue 31's kill test on a site's laptop: `study next` SIGKILLed at a random moment of
    its session, then `study record` SIGKILLed at a random moment; a whole `study record` afterwards leaves
    no outbox entry, nothing `running`, every folder recorded once (tests/_pg_kills.py; 50 rounds:
    benchmarks/bench_study_kills.py --registry postgresql)."""
    from tests._pg_kills import run_sessions

    result = run_sessions(pg_cluster, tmp_path, kills=1, seed=int.from_bytes(os.urandom(4), "little"))
    assert result.trials == 1 and not result.failures, result.failures


def test_a_killed_session_is_resumed_under_its_key(trial, capsys):
    """SIGKILL after a turn of a slow session; `study next --resume` records the killed one from the outbox
    (interrupted), continues its folder under the same key and completes it: one row, counted once."""
    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(north), "P001", "--no-keys",
                             "--user-model", "1", "--turns", "5", "--speed", "12"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=_env(trial.roles["north"]))

    def turns() -> int:
        found = sorted((north / "sessions").glob("P001_*/turns.csv"))
        return len(found[0].read_text().splitlines()) - 1 if found else 0

    try:
        while turns() < 1 and proc.poll() is None:
            threading_wait(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert turns() < 5, "the session ended before the kill"
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "study", "next", str(north), "P001", "--resume",
                          "--no-keys"], capture_output=True, text=True, env=_env(trial.roles["north"]), timeout=240)
    assert res.returncode == 0, res.stderr
    assert "recorded as interrupted (from outbox/)" in res.stderr and "session 1 of 2 (resumed)" in res.stderr
    rows = trial.sql("SELECT number, status, folder FROM sessions")
    assert len(rows) == 1 and rows[0][:2] == (1, "completed") and turns() == 5
    code, _, err = cli(capsys, "next", north, "P001", "--resume", "--no-keys")
    assert code == 2 and "no interrupted session to resume" in err


def test_a_session_killed_while_the_network_is_down_is_resumed_under_its_key(trial, capsys):
    """The site's network is cut (tests/_pg_cluster.py ``Relay``) after the first turn; the session goes on
    locally and is SIGKILLed while the network is still down; with the network back `study next --resume`
    records the killed one from the outbox (interrupted), continues its folder under the same key and
    completes it: one row, every turn on disk, nothing left in the outbox."""
    from tests._pg_cluster import Relay

    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    relay = Relay(trial.cluster, Path(f"/tmp/nt-relay-{uuid.uuid4().hex[:8]}")).start()
    try:
        (north / "registry.url").write_text(relay.url(trial.db) + "\n")
        proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(north), "P001",
                                 "--no-keys", "--user-model", "1", "--turns", "4", "--speed", "12"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                env=_env(trial.roles["north"]))

        def turns() -> int:
            found = sorted((north / "sessions").glob("P001_*/turns.csv"))
            return len(found[0].read_text().splitlines()) - 1 if found else 0

        try:
            while turns() < 1 and proc.poll() is None:
                threading_wait(0.02)
            relay.cut()  # the network goes: the session plays on locally
            while turns() < 2 and proc.poll() is None:
                threading_wait(0.02)
        finally:
            proc.send_signal(signal.SIGKILL)
            _, err = proc.communicate()
        assert 2 <= turns() < 4, f"the session ended before the kill: {err}"
        assert "Traceback" not in err, err
        (entry,) = [json.loads(p.read_text()) for p in (north / "outbox").glob("*.json")]
        assert entry["status"] == "running"
        assert trial.sql("SELECT key, status FROM sessions") == [(entry["key"], "running")]  # before the cut
        code, _, err = cli(capsys, "next", north, "P001", "--resume", "--no-keys")  # the network still down
        assert code == 2 and "cannot reach the registry server" in err and len(err.strip().splitlines()) == 1, err
        assert turns() < 4 and (north / "outbox" / f"{entry['key']}.json").is_file()  # nothing played, entry kept
        relay.restore()
        res = subprocess.run([sys.executable, "-m", "nao_trainer", "study", "next", str(north), "P001", "--resume",
                              "--no-keys"], capture_output=True, text=True, env=_env(trial.roles["north"]),
                             timeout=240)
        assert res.returncode == 0, res.stderr
        assert "recorded as interrupted (from outbox/)" in res.stderr and "session 1 of 2 (resumed)" in res.stderr
        rows = trial.sql("SELECT key, number, status, folder FROM sessions")
        (folder,) = (north / "sessions").glob("P001_*")  # the killed session's folder, continued
        assert len(rows) == 1 and rows[0] == (entry["key"], 1, "completed", folder.name)
        assert turns() == 4 and not list((north / "outbox").glob("*.json"))
        assert [int(r["turn"]) for r in csv.DictReader((folder / "turns.csv").open())] == [1, 2, 3, 4]  # each once
        code, out, _ = cli(capsys, "record", north)
        assert code == 0 and "0 session(s) recorded" in out
    finally:
        relay.cut()
        shutil.rmtree(relay.folder, ignore_errors=True)


def test_an_edited_outbox_entry_is_one_line(trial, capsys):
    north = trial.as_("north")
    (north / "outbox").mkdir()
    for text in ("{", '{"key": "other", "pseudonym": "P001", "number": 1, "status": "completed"}', "[" * 100_000):
        (north / "outbox" / "k1.json").write_text(text)
        code, _, err = cli(capsys, "record", north)
        assert code == 2 and "not a session entry nao-trainer wrote" in err and len(err.strip().splitlines()) == 1


def test_amendments_on_postgresql(trial, capsys):
    """`study amend` by the administrator: before enrolment the sequence of the new design is drawn; after,
    the design is refused and an arm's change needs --change-arms (then the registry holds the arm's new
    configuration, the one `study next` receives); each site's copy of the protocol is replaced by the registry's text at its next command;
    the export counts the amendments."""
    admin_env = trial.roles.copy()
    small = PROTOCOL.replace("block_size: 6", "block_size: 3")
    (trial.tmp / "small.yaml").write_text(small)
    trial.monkeypatch.setenv("PGUSER", "postgres")
    code, out, err = cli(capsys, "amend", trial.admin, trial.tmp / "small.yaml", "--reason", "smaller blocks")
    assert code == 0, err
    from nao_trainer.study.protocol import protocol_hash

    assert trial.sql("SELECT value #>> '{}' FROM meta WHERE key = 'protocol_sha256'")[0][0] == protocol_hash(small)
    assert trial.sql("SELECT count(*) FROM allocation")[0][0] == 12
    north = trial.as_("north")
    assert cli(capsys, "enrol", north, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    assert (north / "protocol.yaml").read_text() == small  # the site's copy follows the registry
    trial.monkeypatch.setenv("PGUSER", "postgres")
    code, _, err = cli(capsys, "amend", trial.admin, trial.tmp / "protocol.yaml", "--reason", "back")
    assert code == 2 and "after enrolment began" in err and len(err.strip().splitlines()) == 1
    changed = small.replace("policy.schedule: [L2]", "policy.schedule: [L3]")
    (trial.tmp / "l3.yaml").write_text(changed)
    code, _, err = cli(capsys, "amend", trial.admin, trial.tmp / "l3.yaml", "--reason", "harder")
    assert code == 2 and "--change-arms" in err and len(err.strip().splitlines()) == 1
    code, out, err = cli(capsys, "amend", trial.admin, trial.tmp / "l3.yaml", "--reason", "harder", "--change-arms")
    assert code == 0 and "CHANGES ARMS: arm level2 changed" in out, err
    config = trial.sql("SELECT config FROM arms WHERE name = 'level2'")[0][0]
    assert config["policy.schedule"] == ["L3"]
    stats = trial.as_("stats")
    assert cli(capsys, "unblind", stats, "--reason", "check")[0] == 0
    code, out, err = cli(capsys, "export", stats, "--bids", trial.tmp / "bids")
    assert code == 0, err
    assert "2 amendment(s)" in (trial.tmp / "bids" / "dataset_description.json").read_text()
    assert (stats / "protocol.yaml").read_text() == changed
    assert admin_env == trial.roles
