"""The registry on a real PostgreSQL server (issue 31 items 2-3): blinding by the database's roles, two
sites enrolling at once against one concealed sequence, a session recorded once after the network came
back, a kill in the middle of enrolments, and one-line errors. One cluster for the whole test session
(conftest ``pg_cluster``); each test its own database."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import uuid
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.errors import ConfigError, DataError
from nao_trainer.study import pg
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.registry import allocation_sequence

ROOT = Path(__file__).resolve().parents[2]
PROTOCOL = ROOT / "config" / "protocols" / "example-3arm.yaml"


class Study:
    def __init__(self, cluster, tmp_path, monkeypatch, stratify_by_site=False):
        self.cluster = cluster
        self.db = "s_" + uuid.uuid4().hex[:10]
        self.prefix = self.db
        self.passfile = tmp_path / "pgpass"
        self.lines = [f"*:*:*:postgres:{cluster.password}"]
        self._write()
        monkeypatch.setenv("PGPASSFILE", str(self.passfile))
        monkeypatch.delenv("PGPASSWORD", raising=False)
        with pg.connect(cluster.url(), autocommit=True) as c:
            c.execute(f"CREATE DATABASE {self.db}")
        self.protocol = load_protocol(PROTOCOL)
        self.sequences = allocation_sequence(self.protocol, np.random.default_rng(7))
        if stratify_by_site:
            self.sequences = {site: allocation_sequence(self.protocol, np.random.default_rng(i))[""]
                              for i, site in enumerate(("north", "south"))}
        self.admin = pg.connect(self.url("postgres"), autocommit=True)
        pg.create(self.admin, self.prefix, self.sequences,
                  {a.name: a.config_overrides() for a in self.protocol.arms}, stratify_by_site,
                  self.protocol.target_n)

    def _write(self):
        self.passfile.write_text("\n".join(self.lines) + "\n")
        self.passfile.chmod(0o600)

    def url(self, user):
        return self.cluster.url(self.db, user)

    def site(self, name):
        role, password = pg.site_add(self.admin, name)
        self.lines.append(f"*:*:*:{role}:{password}")
        self._write()
        return role

    def statistician(self):
        role, password = pg.statistician_add(self.admin, "stats")
        self.lines.append(f"*:*:*:{role}:{password}")
        self._write()
        return role


@pytest.fixture
def study(pg_cluster, tmp_path, monkeypatch):
    s = Study(pg_cluster, tmp_path, monkeypatch)
    yield s
    s.admin.close()


def test_operator_cannot_read_an_arm(study):
    north = study.site("north")
    with pg.connect(study.url(north), autocommit=True) as op:
        pseud = pg.enrol(op, "2026-12-01", "v1")
        # what the operator may see: its site's pseudonyms, consent and session counts
        assert [r["pseudonym"] for r in pg.site_participants(op)] == [pseud]
        # ... and the configuration of the next session (the arm's settings, not its name)
        config = pg.session_config(op, pseud)
        assert config["next_session"] == 1 and "policy.kind" in config["config"]
        arm_names = {a.name for a in study.protocol.arms}
        assert set(config) == {"pseudonym", "next_session", "last_ended", "config"}  # no arm name, no slot
        for sql in ("SELECT arm FROM allocation", "SELECT * FROM allocation", "SELECT * FROM participants",
                    "SELECT stratum, allocation_index FROM participants", "SELECT * FROM arms",
                    "SELECT * FROM unblindings", "SELECT * FROM unblind('curious')"):
            with pytest.raises(ConfigError, match="refused by the registry.*permission denied"):
                pg.call(op, "probe", sql)
    stats = study.statistician()
    with pg.connect(study.url(stats), autocommit=True) as st:
        with pytest.raises(ConfigError, match="permission denied"):
            pg.call(st, "probe", "SELECT arm FROM allocation")  # even the statistician: only through unblind
        arms = pg.unblind(st, "primary analysis")
        assert [p for p, _ in arms] == [pseud] and arms[0][1] in arm_names
        log = pg.call(st, "log", "SELECT who, reason FROM unblindings")
        assert log == [(stats, "primary analysis")]


def test_two_sites_enrol_at_once_balanced_and_concealed(study):
    roles = [study.site("north"), study.site("south")]
    out: dict[str, list[str]] = {r: [] for r in roles}
    errors: list[BaseException] = []

    def run(role):
        try:
            with pg.connect(study.url(role), autocommit=True) as op:
                for _ in range(6):
                    pseud = pg.enrol(op, "2026-12-01", "v1")
                    out[role].append(pseud)
                    for n in (1, 2):  # two sessions each: 24 in all
                        pg.record_session(op, f"{pseud}-{n}", pseud, n, f"{pseud}_{n}", "completed",
                                          {"turns.csv": "0" * 64})
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(r,)) for r in roles]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    everyone = out[roles[0]] + out[roles[1]]
    assert len(set(everyone)) == 12
    # each site's pseudonyms from its own range, each sees only its own
    for role in roles:
        with pg.connect(study.url(role), autocommit=True) as op:
            seen = pg.site_participants(op)
            assert sorted(r["pseudonym"] for r in seen) == sorted(out[role])
            assert all(r["sessions_done"] == 2 for r in seen)
    assert not set(out[roles[0]]) & set(out[roles[1]])
    with pg.connect(study.url(study.statistician()), autocommit=True) as st:
        arms = dict(pg.unblind(st, "check"))
        n_sessions = pg.call(st, "n", "SELECT count(*) FROM sessions")[0][0]
    # one sequence, taken in order: the 12 participants hold its first 12 slots, balanced over the arms
    assert sorted(Counter(arms.values()).items()) == sorted(Counter(study.sequences[""][:12]).items())
    assert set(Counter(arms.values()).values()) == {12 // len(study.protocol.arms)}
    assert n_sessions == 24


def test_stratified_by_site(pg_cluster, tmp_path, monkeypatch):
    s = Study(pg_cluster, tmp_path, monkeypatch, stratify_by_site=True)
    north, south = s.site("north"), s.site("south")
    with pg.connect(s.url(north), autocommit=True) as a, pg.connect(s.url(south), autocommit=True) as b:
        got = {"north": [pg.enrol(a, "2026-12-01", "v1") for _ in range(4)],
               "south": [pg.enrol(b, "2026-12-01", "v1") for _ in range(2)]}
    with pg.connect(s.url(s.statistician()), autocommit=True) as st:
        arms = dict(pg.unblind(st, "check"))
    for site, people in got.items():
        assert [arms[p] for p in people] == s.sequences[site][:len(people)]
    s.admin.close()


def test_session_recorded_once_after_the_network_came_back(study):
    role = study.site("north")
    with pg.connect(study.url(role), autocommit=True) as op:
        pseud = pg.enrol(op, "2026-12-01", "v1")
        pg.record_session(op, "k-1", pseud, 1, f"{pseud}_1", "started", None)
    # the network goes: the laptop finishes locally; when it is back it records the same key, maybe twice
    with pg.connect(study.url(role), autocommit=True) as op:
        for _ in range(2):
            pg.record_session(op, "k-1", pseud, 1, f"{pseud}_1", "completed", {"turns.csv": "a" * 64})
        assert pg.site_participants(op)[0]["sessions_done"] == 1
        with pytest.raises(ConfigError, match="recorded for another session"):
            pg.record_session(op, "k-1", pseud, 2, f"{pseud}_2", "completed", None)
    rows = pg.call(study.admin, "rows", "SELECT key, status FROM sessions")
    assert rows == [("k-1", "completed")]


def test_a_site_records_only_its_own_participants(study):
    north, south = study.site("north"), study.site("south")
    with pg.connect(study.url(north), autocommit=True) as a:
        pseud = pg.enrol(a, "2026-12-01", "v1")
    with pg.connect(study.url(south), autocommit=True) as b:
        with pytest.raises(ConfigError, match="not a participant of your site"):
            pg.session_config(b, pseud)
        with pytest.raises(ConfigError, match="not a participant of your site"):
            pg.record_session(b, "x", pseud, 1, "f", "completed", None)


def test_errors_are_one_line(study, pg_cluster, tmp_path):
    role = study.site("north")
    study.passfile.write_text(f"*:*:*:{role}:wrong\n")
    with pytest.raises(ConfigError, match="refused the credentials") as e:
        pg.connect(study.url(role))
    assert "\n" not in str(e.value)
    with pytest.raises(DataError, match="cannot reach the registry server") as e:
        pg.connect(f"postgresql://x@/db?host={tmp_path / 'nowhere'}")
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="must not carry a password"):
        pg.connect("postgresql://u:secret@localhost/db")


_ENROL_LOOP = """
import sys
from nao_trainer.study import pg
with pg.connect(sys.argv[1], autocommit=True) as op:
    while True:
        pg.enrol(op, "2026-12-01", "v1")
        print("ok", flush=True)
"""


def test_sigkill_while_enrolling_leaves_a_whole_state(study):
    """SIGKILLs of an enrolling process at random moments: every participant holds the next slot of the
    sequence, none is half-written, the survivors continue (the 50-kill version: benchmarks)."""
    role = study.site("north")
    rng = np.random.default_rng()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", _ENROL_LOOP, study.url(role)], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert proc.stdout.readline().strip() == "ok"
        threading.Event().wait(float(rng.uniform(0, 0.05)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
        rows = pg.call(study.admin, "check", "SELECT stratum, allocation_index, number FROM participants "
                       "ORDER BY number")
        assert [r[1] for r in rows] == list(range(len(rows)))
        assert [r[2] for r in rows] == list(range(1, len(rows) + 1))
        if len(rows) >= study.protocol.target_n - 2:
            break


def _cli(capsys, *args) -> tuple[int, str]:
    from nao_trainer.cli import main

    code = main(["study", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out + out.err


def test_command_line_two_sites_from_two_shells(pg_cluster, tmp_path, monkeypatch, capsys):
    """study init --registry, site add x2, statistician add, 12 enrolled from two shells at once as two
    sites, status per role (no arm), the operator refused the unblinding in one line, the statistician's
    unblinding balanced and logged."""
    db = "c_" + uuid.uuid4().hex[:10]
    passfile = tmp_path / "pgpass"
    lines = [f"*:*:*:postgres:{pg_cluster.password}"]
    passfile.write_text(lines[0] + "\n")
    passfile.chmod(0o600)
    monkeypatch.setenv("PGPASSFILE", str(passfile))
    monkeypatch.setenv("PGUSER", "postgres")
    with pg.connect(pg_cluster.url(), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {db}")
    study = tmp_path / "study"
    code, out = _cli(capsys, "init", PROTOCOL, "--out", study, "--registry", pg_cluster.url(db))
    assert code == 0, out
    assert "postgres" not in (study / "registry.url").read_text().split("?")[0].split("//")[1]
    roles = {}
    for who in ("site", "site", "statistician"):
        name = {0: "north", 1: "south"}.get(len(roles), "stats")
        code, out = _cli(capsys, who, "add", study, name)
        assert code == 0, out
        role, password = out.split("role ")[1].split(";")[0], out.strip().rsplit(" ", 1)[1]
        roles[name] = role
        lines.append(f"*:*:*:{role}:{password}")
    passfile.write_text("\n".join(lines) + "\n")
    assert not any(pw.split(":")[-1] in p.read_text(errors="replace") for pw in lines for p in study.rglob("*")
                   if p.is_file())
    env = {**os.environ, "PYTHONPATH": str(ROOT), "QI_LOG_LEVEL": "silent"}
    loop = ("import sys\nfrom nao_trainer.cli import main\nfor _ in range(6):\n"
            "    assert main(['study', 'enrol', sys.argv[1], '--consent-date', '2026-12-01', "
            "'--consent-version', 'v1']) == 0\n")
    shells = [subprocess.Popen([sys.executable, "-c", loop, str(study)], env={**env, "PGUSER": roles[s]},
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for s in ("north", "south")]
    outs = [p.communicate(timeout=120) for p in shells]
    assert [p.returncode for p in shells] == [0, 0], outs
    assert sum(o.count("enrolled (arm concealed") for o, _ in outs) == 12
    monkeypatch.setenv("PGUSER", roles["north"])
    code, out = _cli(capsys, "status", study)
    assert code == 0 and "6 participant(s)" in out and "arms: not readable" in out
    assert not any(a.name in out.split("\n", 2)[2] for a in load_protocol(PROTOCOL).arms)
    code, out = _cli(capsys, "unblind", study, "--reason", "curious")
    assert code == 2 and out.count("\n") == 1 and "permission denied" in out
    code, out = _cli(capsys, "analyse", study)
    assert code == 2 and out.count("\n") == 1 and "the statistician's role only" in out
    monkeypatch.setenv("PGUSER", roles["stats"])
    code, out = _cli(capsys, "status", study)
    assert code == 0 and "north: 6 participant(s)" in out and "south: 6 participant(s)" in out
    code, out = _cli(capsys, "unblind", study, "--reason", "primary analysis")
    assert code == 0
    arms = Counter(line.split("\t")[1] for line in out.splitlines() if "\t" in line)
    assert sorted(arms.values()) == [4, 4, 4]
    code, out = _cli(capsys, "status", study)
    assert "primary analysis" in out and roles["stats"] in out


def test_connection_lost_mid_session_then_recorded_once(study):
    """The server drops the site's connection while its session runs (pg_terminate_backend): the record
    fails in one line, the laptop keeps the session, and records it once on a new connection."""
    role = study.site("north")
    op = pg.connect(study.url(role), autocommit=True)
    pseud = pg.enrol(op, "2026-12-01", "v1")
    pg.record_session(op, "key-1", pseud, 1, f"{pseud}_1", "started", None)
    pid = op.info.backend_pid
    study.admin.execute("SELECT pg_terminate_backend(%s)", (pid,))
    with pytest.raises(DataError, match="lost the registry server") as e:
        pg.record_session(op, "key-1", pseud, 1, f"{pseud}_1", "completed", {"turns.csv": "b" * 64})
    assert "\n" not in str(e.value)
    op.close()
    with pg.connect(study.url(role), autocommit=True) as again:
        pg.record_session(again, "key-1", pseud, 1, f"{pseud}_1", "completed", {"turns.csv": "b" * 64})
        pg.record_session(again, "key-1", pseud, 1, f"{pseud}_1", "completed", {"turns.csv": "b" * 64})
        assert pg.site_participants(again)[0]["sessions_done"] == 1
    assert pg.call(study.admin, "n", "SELECT count(*), min(status) FROM sessions") == [(1, "completed")]


def test_command_line_stratified_by_site(pg_cluster, tmp_path, monkeypatch, capsys):
    """--stratify-by-site: each site's sequence drawn when the site is added, taken in order by that site."""
    db = "t_" + uuid.uuid4().hex[:10]
    passfile = tmp_path / "pgpass"
    lines = [f"*:*:*:postgres:{pg_cluster.password}"]
    passfile.write_text(lines[0] + "\n")
    passfile.chmod(0o600)
    monkeypatch.setenv("PGPASSFILE", str(passfile))
    monkeypatch.setenv("PGUSER", "postgres")
    with pg.connect(pg_cluster.url(), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {db}")
    study = tmp_path / "study"
    assert _cli(capsys, "init", PROTOCOL, "--out", study, "--registry", pg_cluster.url(db),
                "--stratify-by-site")[0] == 0
    roles = {}
    for site in ("north", "south"):
        code, out = _cli(capsys, "site", "add", study, site)
        assert code == 0, out
        roles[site] = out.split("role ")[1].split(";")[0]
        lines.append(f"*:*:*:{roles[site]}:{out.strip().rsplit(' ', 1)[1]}")
    passfile.write_text("\n".join(lines) + "\n")
    for site in ("north", "south"):
        monkeypatch.setenv("PGUSER", roles[site])
        for _ in range(6):
            assert _cli(capsys, "enrol", study, "--consent-date", "2026-12-01", "--consent-version", "v1")[0] == 0
    with pg.connect(pg_cluster.url(db), autocommit=True) as c:
        per = c.execute("SELECT p.site, a.arm FROM participants p JOIN allocation a ON a.stratum = p.stratum "
                        "AND a.position = p.allocation_index ORDER BY p.site, p.allocation_index").fetchall()
        seqs = {site: [r[0] for r in c.execute("SELECT arm FROM allocation WHERE stratum = %s ORDER BY position",
                                               (site,))] for site in ("north", "south")}
        strata = {r[0] for r in c.execute("SELECT DISTINCT stratum FROM participants")}
    assert strata == {"north", "south"}
    arms = sorted(a.name for a in load_protocol(PROTOCOL).arms)
    for site in ("north", "south"):  # each site takes its own sequence in order; each sequence balanced
        assert [arm for s, arm in per if s == site] == seqs[site][:6]
        assert sorted(seqs[site]) == sorted(arms * (len(seqs[site]) // len(arms)))
    assert _cli(capsys, "init", PROTOCOL, "--out", tmp_path / "x", "--stratify-by-site")[0] == 2


def test_allocation_seed_file_with_a_postgresql_registry(pg_cluster, tmp_path, monkeypatch, capsys):
    """--allocation-seed-file with --registry: the sequence drawn from the third party's seed (the same seed,
    the same sequence; the seed stored nowhere); with --stratify-by-site refused in one line."""
    passfile = tmp_path / "pgpass"
    passfile.write_text(f"*:*:*:postgres:{pg_cluster.password}\n")
    passfile.chmod(0o600)
    monkeypatch.setenv("PGPASSFILE", str(passfile))
    monkeypatch.setenv("PGUSER", "postgres")
    seed_file = tmp_path / "seed.txt"
    seed_file.write_text("0x5eed2026\n")
    got = []
    for i in range(2):
        db = f"a{i}_" + uuid.uuid4().hex[:8]
        with pg.connect(pg_cluster.url(), autocommit=True) as c:
            c.execute(f"CREATE DATABASE {db}")
        code, out = _cli(capsys, "init", PROTOCOL, "--out", tmp_path / f"s{i}", "--registry", pg_cluster.url(db),
                         "--allocation-seed-file", seed_file)
        assert code == 0, out
        with pg.connect(pg_cluster.url(db), autocommit=True) as c:
            got.append([r[0] for r in c.execute("SELECT arm FROM allocation WHERE stratum = '' ORDER BY position")])
            stored = " ".join(str(r[0]) for r in c.execute("SELECT value FROM meta"))
        assert str(0x5eed2026) not in stored and "5eed2026" not in stored
    expected = allocation_sequence(load_protocol(PROTOCOL), np.random.default_rng(0x5eed2026))[""]
    assert got == [expected, expected]
    code, out = _cli(capsys, "init", PROTOCOL, "--out", tmp_path / "s9", "--registry", pg_cluster.url("x"),
                     "--allocation-seed-file", seed_file, "--stratify-by-site")
    assert code == 2 and out.count("\n") == 1 and "give one or the other" in out


def test_a_counted_session_is_never_set_back_nor_counted_twice(study):
    """A late 'running' entry of a completed session (a retry's leftover) leaves it completed; a second
    completed session 1 of the same participant under another key (two laptops of one site) is kept as
    'duplicate' and not counted."""
    role = study.site("north")
    with pg.connect(study.url(role), autocommit=True) as op:
        pseud = pg.enrol(op, "2026-12-01", "v1")
        assert pg.record_session(op, "k1", pseud, 1, "f1", "completed", {"a": "0" * 64}, {"ended": "x"}) == "completed"
        assert pg.record_session(op, "k1", pseud, 1, None, "running", None) == "completed"
        assert pg.record_session(op, "k2", pseud, 1, "f2", "completed", None) == "duplicate"
        assert pg.record_session(op, "k2", pseud, 1, "f2", "completed", None) == "duplicate"
        assert pg.site_participants(op)[0]["sessions_done"] == 1
        assert pg.session_config(op, pseud)["next_session"] == 2
    rows = pg.call(study.admin, "rows", "SELECT key, folder, status, entry FROM sessions ORDER BY key")
    assert rows == [("k1", "f1", "completed", {"ended": "x"}), ("k2", "f2", "duplicate", {})]


def test_protocol_strata_on_a_postgresql_registry(pg_cluster, tmp_path, monkeypatch, capsys):
    """A protocol with strata of its own on PostgreSQL: `study enrol --stratum` takes the next slot of that
    stratum's sequence (one sequence per level); a missing or unknown level is refused in one line."""
    text = PROTOCOL.read_text().replace("strata: {}", "strata: {age: [under60, over60]}")
    protocol = tmp_path / "strata.yaml"
    protocol.write_text(text.replace("../studies/demo.yaml", str((PROTOCOL.parent / "../studies/demo.yaml").resolve())))
    db = "r_" + uuid.uuid4().hex[:10]
    passfile = tmp_path / "pgpass"
    lines = [f"*:*:*:postgres:{pg_cluster.password}"]
    passfile.write_text(lines[0] + "\n")
    passfile.chmod(0o600)
    monkeypatch.setenv("PGPASSFILE", str(passfile))
    monkeypatch.setenv("PGUSER", "postgres")
    with pg.connect(pg_cluster.url(), autocommit=True) as c:
        c.execute(f"CREATE DATABASE {db}")
    study = tmp_path / "study"
    code, out = _cli(capsys, "init", protocol, "--out", study, "--registry", pg_cluster.url(db))
    assert code == 0, out
    code, out = _cli(capsys, "site", "add", study, "north")
    role = out.split("role ")[1].split(";")[0]
    lines.append(f"*:*:*:{role}:{out.strip().rsplit(' ', 1)[1]}")
    passfile.write_text("\n".join(lines) + "\n")
    monkeypatch.setenv("PGUSER", role)
    levels = ["over60", "under60", "over60", "over60"]
    for level in levels:
        code, out = _cli(capsys, "enrol", study, "--consent-date", "2026-12-01", "--consent-version", "v1",
                         "--stratum", f"age={level}")
        assert code == 0, out
    for bad, says in ((["--stratum", "age=teen"], "use one of under60, over60"), ([], "stratum 'age' missing")):
        code, out = _cli(capsys, "enrol", study, "--consent-date", "2026-12-01", "--consent-version", "v1", *bad)
        assert code == 2 and out.count("\n") == 1 and says in out, out
    with pg.connect(pg_cluster.url(db), autocommit=True) as c:
        rows = c.execute("SELECT stratum, allocation_index FROM participants ORDER BY number").fetchall()
        strata = {r[0] for r in c.execute("SELECT DISTINCT stratum FROM allocation")}
    assert strata == {"age=under60", "age=over60"}
    assert rows == [("age=over60", 0), ("age=under60", 0), ("age=over60", 1), ("age=over60", 2)]
