"""The session engine against the NAO stand-in over real qi: turn flow, MDP bookkeeping, record."""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from nao_trainer.policies.base import StatelessPolicy
from nao_trainer.session import engine as sess
from nao_trainer.session import machine
from nao_trainer.session.parts import Randomness, Script, SessionPorts
from nao_trainer.session.wiring import run_session
from nao_trainer.session.behaviors import load_behaviors
from nao_trainer.session.config import PROJECT_ROOT, load_config
from nao_trainer.core import mdp, task
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.session.dialogue import load_dialogue
from nao_trainer.answers.simulated import SimulatedParticipant
from nao_trainer.policies.fixed import FixedSchedule, UniformRandom
from nao_trainer.session.record import SessionRecorder, read_events, read_turns


def config(tmp_path: Path, **over):
    values = {"session.turns": 6, "timing.speed": 50.0, "session.output": str(tmp_path), "session.seed": 11}
    values.update({k.replace("__", "."): v for k, v in over.items()})
    return load_config(None, values)


def transcript(path: Path) -> list[dict]:
    return [json.loads(line) for line in (path / "robot_transcript.jsonl").read_text().splitlines()]


def spoken(entries):
    return [e["args"][0] for e in entries if e["method"] == "say"]


def test_demo_session_flow_and_record(tmp_path):
    out = io.StringIO()
    # the demo with its simulated Muse; its session.xdf is checked in test_session_xdf.py (its recorder's stop: ~5 s)
    result = run_session(config(tmp_path, eeg__xdf=False), progress=out)
    assert result.status == "completed" and result.exit_code == 0
    rows = read_turns(result.path)
    assert [int(r["turn"]) for r in rows] == list(range(1, 7))
    assert len(out.getvalue().splitlines()) >= 6 and "turn   6/6" in out.getvalue()

    # MDP bookkeeping: each turn's state follows from the previous state, the action and its outcome.
    prev, prev_success = mdp.START, False
    for r in rows:
        action = mdp.ACTION_NAMES.index(r["action"])
        expected = mdp.NEXT_STATE[prev, action, 0] if prev == mdp.START else mdp.next_state(prev, action, prev_success)
        assert int(r["state"]) == expected
        st = mdp.decode(int(r["state"]))
        assert (int(r["length"]), int(r["feedback"]), int(r["previous_score"])) == (st.length, st.feedback, st.previous)
        success = r["success"] == "True"
        assert success == (r["sequence"] == r["response"])
        assert int(r["score"]) == task.score(st.level, success) and int(r["signed_score"]) == task.signed_score(st.level, success)
        assert len(r["sequence"]) == st.length
        assert float(r["reaction_time"]) <= float(r["completion_time"])
        prev, prev_success = int(r["state"]), success
    assert mdp.ACTION_NAMES.index(rows[0]["action"]) in mdp.LEVEL_ACTIONS
    assert result.total_score == sum(int(r["score"]) for r in rows)

    # What the robot did, in order: posture, greeting, ..., per turn "Level N." then one say per letter, then the beep.
    entries = transcript(result.path)
    said = spoken(entries)
    level_idx = [i for i, s in enumerate(said) if s.startswith("Level ")]
    assert len(level_idx) == 6 + 1  # + the practice round
    for r, i in zip(rows, level_idx[1:]):
        assert said[i] == f"Level {r['level']}."
        assert said[i + 1: i + 1 + int(r["length"])] == list(r["sequence"])
    beeps = [e for e in entries if e["method"] == "playSine"]
    assert len(beeps) == 7 and beeps[0]["args"][0] == 880
    postures = [e["args"][0] for e in entries if e["method"] == "goToPosture"]
    assert postures[0] == "Stand" and postures[-1] == "Crouch"
    # the participant answered through the head buttons
    assert sum(e["method"] == "press" for e in entries) >= sum(len(r["response"]) for r in rows)

    info = json.loads((result.path / "session.json").read_text())
    assert info["status"] == "completed" and info["seed"] == 11 and info["exit_code"] == 0
    assert info["config"]["values"]["session"]["turns"] == 6 and len(info["config"]["sha256"]) == 64
    assert info["versions"]["qi"] and info["versions"]["transitions"]
    events = [e["event"] for e in read_events(result.path)]
    assert events.count("turn_end") == 6 and "transition" in events and events[0] == "session_start"


def test_feedback_actions_say_feedback_on_the_last_outcome_then_same_length(tmp_path):
    cfg = config(tmp_path, policy__kind="schedule", policy__schedule=["L2", "RF1", "RF2", "L1"], session__turns=4,
                 session__practice=False, eeg__mode="off")
    result = run_session(cfg, progress=None)
    rows = read_turns(result.path)
    assert [r["action"] for r in rows] == ["L2", "RF1", "RF2", "L1"]
    assert [int(r["length"]) for r in rows] == [5, 5, 5, 3]
    assert [int(r["feedback"]) for r in rows] == [0, 1, 2, 0]
    said = spoken(transcript(result.path))
    dialogue = load_dialogue(PROJECT_ROOT / "dialogue" / "en.yaml")
    for k, (style, r_prev) in enumerate(zip(("encouraging", "challenging"), rows[:2]), start=1):
        outcome = "success" if r_prev["success"] == "True" else "failure"
        level_positions = [i for i, s in enumerate(said) if s.startswith("Level ")]
        before = said[level_positions[k] - 1]
        assert before in dialogue.variants[f"{style}_{outcome}"], (before, style, outcome)
        assert int(rows[k]["previous_score"]) == int(r_prev["signed_score"])


@pytest.mark.slow
def test_same_seed_same_session(tmp_path):
    # the simulated Muse stays on (engagement must not make the session depend on the clock); session.xdf
    # is only a recording of the streams, and its recorder's start and stop cost ~6 s a session
    quick = {"session__turns": 4, "session__practice": False, "eeg__xdf": False}
    a = run_session(config(tmp_path / "a", **quick), progress=None)
    b = run_session(config(tmp_path / "b", **quick), progress=None)
    c = run_session(config(tmp_path / "c", session__seed=12, **quick), progress=None)
    # what the seed decides: actions, sequences and the simulated participant's intended answers
    # (delivered presses go through qi and the clock, so they are compared in the flow test instead)
    def key(res):
        plans = [e["response"] for e in read_events(res.path) if e["event"] == "simulated_plan"]
        return [(r["action"], r["sequence"]) for r in read_turns(res.path)], plans
    assert key(a) == key(b)
    assert key(a) != key(c)


class RecordingPolicy(StatelessPolicy):
    """A policy that plays L1 then RF1 forever and keeps what the session reports to it."""

    name = "recording"

    def __init__(self):
        self.seen, self.closed = [], False

    def act(self, state, rng):
        return 0 if state == mdp.START else 4

    def observe(self, transition):
        self.seen.append(transition)

    def status(self):
        return {}

    def close(self):
        self.closed = True


def test_policy_gets_every_transition(tmp_path):
    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    cfg = config(tmp_path, session__turns=4, session__practice=False)
    standin = StandIn.start(speed=50)
    robot = NaoqiRobot.connect(standin.url, 5.0)
    rec = SessionRecorder(tmp_path, "T")
    rec.open({})
    sim = UserSimulator.from_level_rates("always", [1, 1, 1, 1])
    policy = RecordingPolicy()
    try:
        s = sess.Session(cfg, SessionPorts(robot, SimulatedParticipant(sim, np.random.default_rng(0), 50), policy), rec,
                         Script(load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path)),
                         Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=None)
        assert s.run() == 0 and s.state == "done"
    finally:
        rec.close("completed", 0)
        robot.close()
        standin.stop()
    t = policy.seen
    assert [x.state for x in t] == [mdp.START, mdp.encode(3, 0, 0), mdp.encode(3, 1, 1), mdp.encode(3, 1, 1)]
    assert [x.action for x in t] == [0, 4, 4, 4] and [x.score for x in t] == [1, 1, 1, 1]
    assert [x.done for x in t] == [False, False, False, True]
    assert all(x.engagement is None for x in t)  # EEG off
    assert t[1].next_state == mdp.encode(3, 1, 1)


def test_fixed_schedule_and_uniform_random_policies():
    sched = FixedSchedule(["L3", "RF2"])
    rng = np.random.default_rng(0)
    assert [sched.act(mdp.START, rng)] + [sched.act(5, rng) for _ in range(3)] == [2, 5, 2, 5]
    rand = UniformRandom()
    first = {rand.act(mdp.START, np.random.default_rng(s)) for s in range(60)}
    later = {rand.act(10, np.random.default_rng(s)) for s in range(60)}
    assert first == {0, 1, 2, 3} and later == set(range(6))
    assert [rand.act(10, np.random.default_rng(4)) for _ in range(3)] == [rand.act(10, np.random.default_rng(4))] * 3


def test_state_diagram_in_docs_is_up_to_date():
    assert machine.DIAGRAM_PATH.read_text() == machine.diagram_markdown(), \
        "docs/reference/session-states.md is stale: run python -c 'from nao_trainer.session.machine import export_diagram; export_diagram()'"
    text = machine.diagram_markdown()
    for state in machine.STATES:
        assert f'state "{state}"' in text
    assert "paused --> select_action: resume_turn" in text


def test_a_refused_posture_is_logged_and_the_session_goes_on(tmp_path):
    import dataclasses

    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    cfg = config(tmp_path, session__turns=2, session__practice=False)
    behaviors = dataclasses.replace(load_behaviors(cfg.session.behaviors_path), start_posture="Kneel")
    standin = StandIn.start(speed=50)
    robot = NaoqiRobot.connect(standin.url, 5.0)
    rec = SessionRecorder(tmp_path, "R")
    path = rec.open({})
    try:
        participant = SimulatedParticipant(UserSimulator.from_level_rates("x", [1, 1, 1, 1]), np.random.default_rng(0), 50)
        s = sess.Session(cfg, SessionPorts(robot, participant, UniformRandom()), rec,
                         Script(load_dialogue(cfg.session.dialogue_path), behaviors),
                         Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=None)
        assert s.run() == 0
    finally:
        rec.close("completed", 0)
        robot.close()
        standin.stop()
    failed = [e for e in read_events(path) if e["event"] == "robot_call_failed"]
    assert len(failed) == 1 and failed[0]["what"] == "posture Kneel" and "unknown posture" in failed[0]["error"]
    assert len(read_turns(path)) == 2


def test_after_a_reconnection_the_buttons_are_subscribed_once(tmp_path):
    from nao_trainer.answers.inputs import TactileAnswers
    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    cfg = config(tmp_path, session__turns=1, session__practice=False)
    standin = StandIn.start(speed=50)
    robot = NaoqiRobot.connect(standin.url, 5.0, debounce_s=0.01)
    rec = SessionRecorder(tmp_path, "B")
    rec.open({})
    tactile = TactileAnswers(robot, debounce_s=0.01, grace_s=0.1)
    subscribed = []
    subscribe = robot.subscribe_buttons
    robot.subscribe_buttons = lambda callback: (subscribed.append(callback), subscribe(callback))[1]
    try:
        s = sess.Session(cfg, SessionPorts(robot, tactile, UniformRandom()), rec,
                         Script(load_dialogue(cfg.session.dialogue_path), load_behaviors(cfg.session.behaviors_path)),
                         Randomness(np.random.default_rng(1), np.random.default_rng(2)), progress=None)
        assert s.reconnector.reconnect()
        assert len(subscribed) == 1  # NaoqiRobot.reconnect re-subscribes; nobody else does it again
        tactile.open_window()
        standin.press("A")
        assert tactile.collect(1, timeout_s=3.0).response == ("A",)
    finally:
        tactile.close()
        rec.close("completed", 0)
        robot.close()
        standin.stop()


def test_a_session_with_a_negative_total_says_goodbye_without_the_number(tmp_path):
    study = tmp_path / "never-right.yaml"
    study.write_text("participant_model: {user_model: null, success_by_level: [0, 0, 0, 0]}\n")
    cfg = load_config(study, {"session.turns": 3, "timing.speed": 50.0, "session.output": str(tmp_path),
                              "session.seed": 11, "session.practice": False})
    result = run_session(cfg)
    assert result.status == "completed" and result.total_score < 0
    goodbye = [e for e in read_events(result.path) if e["event"] == "say" and e["what"].startswith("goodbye")]
    assert [e["what"] for e in goodbye] == ["goodbye_no_points"]
    assert str(result.total_score) not in goodbye[0]["text"] and "points" not in goodbye[0]["text"]
    assert goodbye[0]["text"] in spoken(transcript(result.path))
