"""The study protocol, the registry and their bad input: one line each, exit 2, nothing written."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

import numpy as np

from _study_data import PROTOCOL, SWAP, edit_registry, registry_state, write_protocol
from nao_trainer.cli import main
from nao_trainer.files import PROJECT_ROOT
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.registry import allocation_sequence, open_study

def cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def test_the_shipped_example_protocol_loads():
    p = load_protocol(PROJECT_ROOT / "config" / "protocols" / "example-3arm.yaml")
    assert [a.name for a in p.arms] == ["personalised", "level2", "random"] and p.blinding
    assert p.primary == "span" and p.analysis.terms == ("arm", "session") and len(p.sha256) == 64
    assert p.analysis.primary_contrast == "personalised" and p.analysis.variance == "arm"


def test_blocked_allocation_has_random_block_sizes_and_stays_balanced(tmp_path):
    p = load_protocol(write_protocol(tmp_path))
    seq = allocation_sequence(p, np.random.default_rng(1))[""]
    assert seq == allocation_sequence(p, np.random.default_rng(1))[""]  # the seed decides (not the protocol's)
    first_three_balanced = set()
    for seed in range(60):
        seq = allocation_sequence(p, np.random.default_rng(seed))[""]
        assert len(seq) >= 12 and len(seq) % 3 == 0 and set(Counter(seq).values()) == {len(seq) // 3}
        for n in range(1, len(seq) + 1):  # blocks of 3 or 6: no arm ever more than 2 ahead of another
            counts = Counter(seq[:n])
            assert max(counts.values()) - min(counts[a] for a in ("personalised", "level2", "random")) <= 2
        first_three_balanced.add(len(Counter(seq[:3])) == 3)
    assert first_three_balanced == {True, False}  # a first block of 3 sometimes, of 6 other times


BAD = {
    "unknown policy": (("policy: random}", "policy: randomised}"), "unknown policy 'randomised'"),
    "cannot balance": (("block_size: 6", "block_size: 4"), "cannot balance 3 arms"),
    "arm with nobody": (("target_n: 12", "target_n: 2"), "arm with no participants possible"),
    "ratio zero": (("policy: random}", "policy: random, ratio: 0}"), "no participants possible"),
    "unknown key": (("blinding: false", "blinding: false\nblind: true"), "unknown key"),
    "bad model": (("(1|participant)", "(1|session)"), "not a model this analysis fits"),
    "bad override": (("policy.schedule: [L2]", "policy.shedule: [L2]"), "not a study configuration key"),
    "bad override value": (("[L2]", "[L7]"), "does not load"),
    "unknown outcome": (("primary: score", "primary: points"), "unknown outcome 'points'"),
    "policy-set primary": (("primary: score", "primary: success_rate"), "is set by the policy"),
    "bad primary contrast": (("reference_arm: level2}", "reference_arm: level2, primary_contrast: level2}"),
                             "is not an arm other than the reference"),
    "bad variance": (("reference_arm: level2}", "reference_arm: level2, variance: robust}"), "use arm"),
    "bad missing rule": (("reference_arm: level2}", "reference_arm: level2, missing: complete-case}"),
                         "use observed-sessions"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_protocols_are_refused_in_one_line_with_the_line_and_nothing_written(tmp_path, capsys, case):
    (old, new), message = BAD[case]
    assert old in PROTOCOL
    path = write_protocol(tmp_path, PROTOCOL.replace(old, new))
    code, out, err = cli(capsys, "study", "init", path, "--out", tmp_path / "study")
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert f"{path}:" in err  # file:line
    assert not (tmp_path / "study").exists()


def _init(tmp_path, capsys, text: str = PROTOCOL) -> Path:
    code, _, err = cli(capsys, "study", "init", write_protocol(tmp_path, text), "--out", tmp_path / "study")
    assert code == 0, err
    return tmp_path / "study"


def test_enrolment_follows_the_concealed_sequence_and_records_consent(tmp_path, capsys):
    study = _init(tmp_path, capsys)
    code, out, _ = cli(capsys, "study", "status", study)
    assert code == 0 and "enrolled 0 of 12" in out and "level2" in out  # arms named (not blinded), no sequence
    arms = []
    for i in range(12):
        code, out, err = cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v3")
        assert code == 0, err
        assert out.startswith(f"P{i + 1:03d}: enrolled (arm ")
        arms.append(out.split("(arm ")[1].split(";")[0])
    assert arms == [open_study(study).arm_of(f"P{i:03d}") for i in range(1, 13)]
    assert Counter(arms) == {"personalised": 4, "level2": 4, "random": 4}
    reg = open_study(study).registry
    assert reg["participants"][0]["consent_date"] == "2026-11-02" and reg["participants"][0]["consent_version"] == "v3"
    code, _, err = cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v3")
    assert code == 2 and "target_n 12" in err


@pytest.mark.parametrize("date", ["02/11/2026", "2999-01-01"])
def test_a_bad_consent_date_is_refused_and_nothing_written(tmp_path, capsys, date):
    study = _init(tmp_path, capsys)
    before = registry_state(study)
    code, _, err = cli(capsys, "study", "enrol", study, "--consent-date", date, "--consent-version", "v1")
    assert code == 2 and "consent date" in err and registry_state(study) == before


def test_blinded_enrolment_does_not_show_the_arm(tmp_path, capsys):
    study = _init(tmp_path, capsys, PROTOCOL.replace("blinding: false", "blinding: true"))
    code, out, _ = cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    assert code == 0 and "concealed" in out and not any(a in out for a in ("level2", "random", "personalised"))
    code, out, _ = cli(capsys, "study", "status", study)
    assert "hidden, blinded" in out and "level2" not in out


@pytest.mark.parametrize("what", ["registry", "protocol", "allocation"])
def test_a_tampered_study_folder_is_refused_in_one_line(tmp_path, capsys, what):
    study = _init(tmp_path, capsys)
    cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    if what == "registry":
        edit_registry(study, "UPDATE participants SET consent_version = 'v2'")
    elif what == "protocol":
        (study / "protocol.yaml").write_text((study / "protocol.yaml").read_text().replace("max: 7", "max: 9"))
    else:  # two sealed slots swapped: each is a valid ciphertext of the study key
        edit_registry(study, SWAP)
    before = (study / "registry.db").read_bytes()
    for args in (("status", study), ("enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")):
        code, _, err = cli(capsys, "study", *args)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert any(w in err for w in ("edited outside nao-trainer", "altered")), err
    assert (study / "registry.db").read_bytes() == before


def test_the_frozen_protocol_changes_only_by_a_recorded_amendment(tmp_path, capsys):
    study = _init(tmp_path, capsys)
    code, _, err = cli(capsys, "study", "init", tmp_path / "protocol.yaml", "--out", study)
    assert code == 2 and "frozen" in err
    cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    changed = write_protocol(tmp_path, PROTOCOL.replace("max: 7", "max: 10"), "v2.yaml")
    with pytest.raises(SystemExit) as stop:  # no reason: argparse refuses with its usage line, exit 2
        main(["study", "amend", str(study), str(changed)])
    assert stop.value.code == 2 and "--reason" in capsys.readouterr().err
    code, out, err = cli(capsys, "study", "amend", study, changed, "--reason", "holidays")
    assert code == 0, err
    reg = open_study(study).registry
    (entry,) = reg["amendments"]
    assert entry["reason"] == "holidays" and entry["new_sha256"] == load_protocol(changed).sha256
    assert open_study(study).protocol.sessions.max_days == 10
    redesign = write_protocol(tmp_path, PROTOCOL.replace("block_size: 6", "block_size: 3"), "v3.yaml")
    code, _, err = cli(capsys, "study", "amend", study, redesign, "--reason", "x")
    assert code == 2 and "after enrolment began" in err and len(open_study(study).registry["amendments"]) == 1


def test_an_amended_copy_resolves_its_paths_wherever_it_lives(tmp_path, capsys):
    """Issue 29: an edited copy of STUDY_DIR/protocol.yaml, saved anywhere, resolves its relative study_config
    against its own folder when the file is there, else against the study's (docs/how-to/study.md, "Amending")."""
    study = _init(tmp_path, capsys)
    elsewhere = tmp_path / "drafts"
    elsewhere.mkdir()
    v2 = elsewhere / "protocol-v2.yaml"  # no base.yaml beside it: the study's folder's is meant
    v2.write_text((study / "protocol.yaml").read_text().replace("max: 7", "max: 10"))
    code, out, err = cli(capsys, "study", "amend", study, v2, "--reason", "holidays")
    assert code == 0, err
    assert f"study configuration {tmp_path / 'base.yaml'}" in out
    assert open_study(study).protocol.study_config == tmp_path / "base.yaml"
    own = tmp_path / "own"
    own.mkdir()
    (own / "base.yaml").write_text((tmp_path / "base.yaml").read_text() + "\n# the site's own\n")
    (own / "v3.yaml").write_text(v2.read_text().replace("max: 10", "max: 9"))
    code, out, err = cli(capsys, "study", "amend", study, own / "v3.yaml", "--reason", "own configuration")
    assert code == 0 and f"study configuration {own / 'base.yaml'}" in out, err
    reopened = open_study(study)  # the frozen copy resolves against the folder recorded with the amendment
    assert reopened.protocol.study_config == own / "base.yaml" and reopened.protocol.sessions.max_days == 9
    (elsewhere / "v4.yaml").write_text(v2.read_text().replace("study_config: base.yaml", "study_config: gone.yaml"))
    code, _, err = cli(capsys, "study", "amend", study, elsewhere / "v4.yaml", "--reason", "x")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{elsewhere / 'gone.yaml'} nor {own / 'gone.yaml'} is not a file" in err and "then the study's" in err


def test_withdrawal_is_recorded_with_what_happens_to_the_data(tmp_path, capsys):
    study = _init(tmp_path, capsys)
    for _ in range(2):
        cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    code, _, err = cli(capsys, "study", "withdraw", study, "P009", "--data", "keep")
    assert code == 2 and "not enrolled" in err
    code, out, _ = cli(capsys, "study", "withdraw", study, "P002", "--data", "keep", "--reason", "moved away")
    assert code == 0 and "withdrawal recorded" in out
    p = open_study(study).participants[1]
    assert p["withdrawn"]["data"] == "keep" and p["withdrawn"]["reason"] == "moved away"
    code, _, err = cli(capsys, "study", "next", study, "P002", "--no-keys")
    assert code == 2 and "withdrew" in err
    code, _, err = cli(capsys, "study", "next", study, "P404", "--no-keys")
    assert code == 2 and "not enrolled" in err


def test_a_second_study_next_for_a_running_participant_is_refused_and_a_stale_lock_taken_over(tmp_path):
    from nao_trainer.study.runner import participant_lock

    for _ in range(1):
        main(["study", "init", str(write_protocol(tmp_path)), "--out", str(tmp_path / "study")])
        main(["study", "enrol", str(tmp_path / "study"), "--consent-date", "2026-11-02", "--consent-version", "v1"])
    study = open_study(tmp_path / "study")
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / "study" / "locks").mkdir()
        lock = tmp_path / "study" / "locks" / "P001.lock"
        import socket

        lock.write_text(json.dumps({"pid": sleeper.pid, "host": socket.gethostname(), "started": "now"}))
        env = dict(os.environ, QI_LOG_LEVEL="silent")
        res = subprocess.run([sys.executable, "-m", "nao_trainer", "study", "next", str(tmp_path / "study"), "P001",
                              "--no-keys"], capture_output=True, text=True, env=env, timeout=120)
        assert res.returncode == 2 and "is running" in res.stderr and len(res.stderr.strip().splitlines()) == 1
        assert lock.exists() and not any((tmp_path / "study" / "sessions").glob("P001_*"))
    finally:
        sleeper.kill()
        sleeper.wait()
    with participant_lock(study, "P001"):  # its process is gone: stale, taken over
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists()


def test_a_blinded_study_serves_a_console_without_the_arm(tmp_path, capsys):
    import threading
    import time
    import urllib.parse
    import urllib.request

    from nao_trainer.console.server import HEADER

    study = _init(tmp_path, capsys, PROTOCOL.replace("blinding: false", "blinding: true"))
    cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(study), "P001", "--console",
                             "--no-keys", "--speed", "25", "--turns", "8"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    lines: list[str] = []
    linked = threading.Event()

    def drain() -> None:  # every line, in a thread: communicate() after a partial read would lose buffered ones
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("console: http"):
                linked.set()
        linked.set()

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    assert linked.wait(240) and any(x.startswith("console: http") for x in lines), "".join(lines)[-2000:]
    link = urllib.parse.urlsplit(next(x for x in lines if x.startswith("console: http")).split()[1])
    token = urllib.parse.parse_qs(link.query)["token"][0]
    request = urllib.request.Request(f"{link.scheme}://{link.netloc}{link.path}state", headers={HEADER: token})
    state: dict = {}
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not state.get("rows"):  # the page's state once a turn is played
        try:
            state = json.loads(urllib.request.urlopen(request, timeout=10).read())
        except OSError:
            break  # the session (and its console) ended
        time.sleep(0.2)
    proc.wait(timeout=240)
    reader.join(timeout=60)
    out, err = proc.stdout.read(), ""
    assert proc.returncode == 0, "".join(lines)[-2000:]
    assert state.get("rows") and state["session"]["policy"] == "arm (blinded)"
    page = json.dumps(state).lower()
    assert not any(w in page for w in ("personalised", "assessment", "usp:", "probabilities"))
    low = ("".join(lines) + out + err).lower()
    assert "the arm is not shown" in low
    assert not any(w in low for w in ("personalised", "level2", "random", "schedule", "assessment", "posterior"))


def test_the_blind_observer_keeps_the_arm_out_of_the_console():
    from nao_trainer.console.server import ConsoleHub
    from nao_trainer.study.runner import BlindObserver

    hub = ConsoleHub()
    seen = BlindObserver(hub)
    seen.notify("session", {"turns": 25, "policy": "personalised", "speed": 1.0})
    seen.notify("turn_start", {"turn": 1, "level": 2, "probabilities": [0, 1, 0, 0, 0, 0], "phase": "assessment"})
    seen.notify("policy", {"turn": 1, "posterior": [0.2, 0.3, 0.5], "following": "usp:2"})
    seen.notify("row", {"turn": 1, "level": 2, "score": 2, "phase": "assessment"})
    seen.notify("summary", {"total_score": 2, "policy_summary": "matched cluster 2"})
    _seq, text = hub.snapshot()
    assert "personalised" not in text and "assessment" not in text and "usp" not in text and "matched" not in text
    assert hub.state["session"]["policy"] == "arm (blinded)" and hub.state["rows"][0]["score"] == 2
    assert hub.state["policy_status"] is None and "probabilities" not in hub.state["turn"]


def test_strata_have_their_own_balanced_sequences(tmp_path, capsys):
    text = PROTOCOL.replace("seed: 7}", "seed: 7, strata: {age: [young, old]}}")
    study = _init(tmp_path, capsys, text)
    code, _, err = cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    assert code == 2 and "--stratum age=young|old" in err
    for level in ("young", "old") * 3:
        code, _, err = cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1",
                           "--stratum", f"age={level}")
        assert code == 0, err
    opened = open_study(study)
    for level in ("young", "old"):  # one sequence per stratum: each stratum's positions count from 0
        mine = [p for p in opened.participants if p["stratum"] == f"age={level}"]
        assert [p["allocation_index"] for p in mine] == [0, 1, 2]
        assert all(opened.arm_of(p["pseudonym"]) in ("personalised", "level2", "random") for p in mine)


def test_a_session_that_fails_after_writing_its_folder_is_recorded_and_not_counted(tmp_path, capsys, monkeypatch):
    from nao_trainer.errors import RobotUnavailable
    from nao_trainer.session import wiring

    study = _init(tmp_path, capsys)
    cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")

    def lost(config, options, progress=None, resume=None):  # the robot is lost for good after the folder exists
        folder = config.output_dir() / f"{config.participant.pseudonym}_20261202-100000"
        folder.mkdir(parents=True)
        (folder / "session.json").write_text(json.dumps({"status": "robot lost", "exit_code": 3,
                                                         "started": "2026-12-02T10:00:00+00:00"}))
        raise RobotUnavailable("lost the robot at 192.0.2.1")

    monkeypatch.setattr(wiring, "run_session", lost)
    code, _, err = cli(capsys, "study", "next", study, "P001", "--no-keys")
    assert code == 3 and "lost the robot" in err
    (entry,) = open_study(study).participants[0]["sessions"]
    assert entry["status"] == "robot lost" and entry["number"] == 1
    assert not (study / "locks" / "P001.lock").exists()
    code, out, _ = cli(capsys, "study", "status", study)
    assert "complete 0" in out and "robot lost" in out


@pytest.mark.slow
def test_an_interrupted_session_is_resumed_through_the_study_and_then_counts(tmp_path, capsys):
    import signal
    import time

    study = _init(tmp_path, capsys)
    cli(capsys, "study", "enrol", study, "--consent-date", "2026-11-02", "--consent-version", "v1")
    code, _, err = cli(capsys, "study", "next", study, "P001", "--resume")
    assert code == 2 and "no interrupted session" in err
    env = dict(os.environ, QI_LOG_LEVEL="silent")
    proc = subprocess.Popen([sys.executable, "-m", "nao_trainer", "study", "next", str(study), "P001", "--no-keys",
                             "--speed", "25", "--turns", "12"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait for two completed turns, then stop it as a crash would
        turns = list((study / "sessions").glob("P001_*/checkpoint.json"))
        if turns and json.loads(turns[0].read_text()).get("completed", 0) >= 2:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    (entry,) = open_study(study).participants[0]["sessions"]
    assert entry["status"] == "interrupted"
    code, _, err = cli(capsys, "study", "next", study, "P001", "--resume", "--speed", "9")
    assert code == 2 and "drop the flags" in err
    res = subprocess.run([sys.executable, "-m", "nao_trainer", "study", "next", str(study), "P001", "--resume",
                          "--no-keys"], capture_output=True, text=True, env=env, timeout=240)
    assert res.returncode == 0 and "session 1 of 2 (resumed)" in res.stderr, res.stderr[-2000:]
    (entry,) = open_study(study).participants[0]["sessions"]
    assert entry["status"] == "completed" and entry["number"] == 1
    with open(study / "sessions" / entry["folder"] / "turns.csv", newline="") as fh:
        assert len([r for r in csv.DictReader(fh) if r["success"] in ("True", "False")]) == 12


@pytest.mark.parametrize("order", ["before", "after"])
def test_the_session_table_form_still_parses_with_its_options_anywhere(tmp_path, capsys, order):
    empty = tmp_path / "empty"
    empty.mkdir()
    args = ["--out", tmp_path / "o", empty] if order == "before" else [empty, "--out", tmp_path / "o", "--no-figure"]
    code, _, err = cli(capsys, "study", *args)
    assert code == 2 and "no session folders written by `nao-trainer run`" in err  # read as a session table
