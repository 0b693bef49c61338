"""A whole session over real qi while the robot reports on its health (issue 27 item 1): the stand-in falls,
heats a knee, runs low on battery and has its chest button pressed at known points of the session (armed
inside the stand-in after a given call), and the session pauses, sits, ends or replays as it should."""
from __future__ import annotations

import threading
from pathlib import Path

import pytest

from nao_trainer.ports import CommandQueue
from nao_trainer.robot.standin import StandIn
from nao_trainer.session.config import load_config
from nao_trainer.session.record import read_events, read_turns
from nao_trainer.session.wiring import RunOptions, run_session
from tests._waits import HANG_S, returns


def _config(tmp_path: Path, url: str, **over):
    values = {"session.turns": 3, "timing.speed": 50.0, "session.output": str(tmp_path), "session.seed": 4,
              "session.practice": False, "robot.url": url, "eeg.mode": "off", "policy.kind": "schedule",
              "answers.input": "simulated", "participant.pseudonym": "P1"}
    values.update(over)
    return load_config(None, values)


class _Watcher:
    """Observes the session; ``when(kind, test)`` gives an Event set once a matching notification arrived."""

    def __init__(self) -> None:
        self.seen: list[tuple[str, dict]] = []
        self._waits: list[tuple[str, object, threading.Event]] = []
        self._lock = threading.Lock()

    def when(self, kind, test=lambda d: True) -> threading.Event:
        event = threading.Event()
        with self._lock:
            self._waits.append((kind, test, event))
        return event

    def notify(self, kind, data):
        with self._lock:
            self.seen.append((kind, dict(data)))
            for k, test, event in self._waits:
                if k == kind and test(data):
                    event.set()


def _play(config, options):
    return returns(lambda: run_session(config, options))


@pytest.fixture
def standin():
    s = StandIn.start(speed=50)
    yield s
    s.stop()


def test_a_fall_pauses_and_the_motors_stay_off_until_the_operator_says_the_robot_is_up(tmp_path, standin):
    standin.control.act_after("ALAudioPlayer.playSine", "fall", [])  # at turn 1's beep
    commands, watcher = CommandQueue(), _Watcher()
    paused = watcher.when("pause", lambda d: d.get("paused"))

    def operator():
        assert paused.wait(HANG_S), "the session never paused after the fall"
        calls_at_pause = len(standin.transcript())
        standin.control.stand_up()
        woken_while_paused.extend(c for c in standin.transcript()[:] if c["method"] == "wakeUp")
        marks.append(calls_at_pause)
        commands.submit("resume", source="test")

    woken_while_paused, marks = [], []
    helper = threading.Thread(target=operator, daemon=True)
    helper.start()
    result = _play(_config(tmp_path, standin.url), RunOptions(quiet=True, commands=commands, observer=watcher))
    helper.join(HANG_S)
    assert result.status == "completed"
    folder = result.path
    events = read_events(folder)
    health = [e for e in events if e["event"] == "robot_health"]
    assert {"falling", "fallen"} <= {e["kind"] for e in health}
    calls = [(c["service"], c["method"]) for c in standin.transcript()]
    fell = calls.index(("NaoTrainerStandIn", "fall"))
    resumed = next(i for i, c in enumerate(standin.transcript()) if c["method"] == "stand_up")
    assert ("ALMotion", "wakeUp") not in calls[fell:resumed]  # never woken on the floor
    assert ("ALMotion", "wakeUp") in calls[resumed:]  # woken once the operator said it is up
    assert [e["event"] for e in events].count("motors_held") == 1
    rows = read_turns(folder)
    assert sum(r["success"] in ("True", "False") for r in rows) == 3  # all played (one replayed if the fall cut it)


def test_battery_low_finishes_the_turn_then_ends_cleanly_with_what_to_do(tmp_path, standin):
    standin.control.act_after("ALAudioPlayer.playSine", "battery_low", [])  # during turn 1
    result = _play(_config(tmp_path, standin.url, **{"session.turns": 4}), RunOptions(quiet=True))
    assert result.status == "battery low" and result.exit_code == 0
    folder = next(tmp_path.glob("*_*"))
    rows = read_turns(folder)
    assert [r["success"] in ("True", "False") for r in rows] == [True]  # the turn in flight finished, scored
    events = read_events(folder)
    assert any(e["event"] == "battery_low_end" for e in events)
    assert any(e["event"] == "robot_health" and e["kind"] == "battery_low" and "charge the robot" in e["decision"]
               for e in events)


@pytest.mark.parametrize("version", ["2.8.5.10", "2.8.7.4"])
def test_battery_low_is_seen_once_with_or_without_the_removed_battery_low_event(tmp_path, version):
    """NAOqi 2.8.6 removed ALBattery/BatteryLow (news/2.8/whatsnew2.8.6.html): a stand-in playing 2.8.7.4 raises only
    BatteryChargeChanged 10 (albattery-api.html), a 2.8.5 one both; either way the session sees one battery low,
    finishes the turn and ends cleanly. Without the BatteryChargeChanged watch, the 2.8.7 session plays all 4 turns."""
    from nao_trainer.robot.profile import Profile

    robot = StandIn.start(speed=50, profile=Profile(naoqi_version=version))
    try:
        robot.control.act_after("ALAudioPlayer.playSine", "battery_low", [])
        result = _play(_config(tmp_path, robot.url, **{"session.turns": 4}), RunOptions(quiet=True))
    finally:
        robot.stop()
    assert result.status == "battery low" and result.exit_code == 0
    low = [e for e in read_events(result.path) if e["event"] == "robot_health" and e["kind"] == "battery_low"]
    assert len(low) == 1 and "charge the robot" in low[0]["decision"]
    if version == "2.8.7.4":
        assert low[0]["detail"] == "battery low (10%): it will soon need charging" and low[0]["value"] == 10
    assert len([r for r in read_turns(result.path) if r["success"] in ("True", "False")]) == 1


def test_a_chest_press_during_a_trial_replays_that_turn(tmp_path, standin):
    standin.control.act_after("ALAudioPlayer.playSine", "chest", [1])  # NAO says its IP over turn 1's answer
    result = _play(_config(tmp_path, standin.url), RunOptions(quiet=True))
    assert result.status == "completed"
    folder = next(tmp_path.glob("*_*"))
    rows = read_turns(folder)
    first = rows[0]
    assert first["invalid"] == "True" and "chest button" in first["notes"]  # marked invalid, never learned from
    again = rows[1]  # played again: the same turn (interrupted, then replayed) or, once scored, its action next
    assert again["action"] == first["action"]
    assert again["success"] in ("True", "False") and not again.get("invalid")
    commands = [e for e in read_events(folder) if e["event"] == "command" and e["source"] == "robot"]
    assert [(c["kind"], c["accepted"]) for c in commands] == [("repeat", True)]


def _calls(standin):
    return [(c["service"], c["method"]) for c in standin.transcript()]


@pytest.mark.parametrize("does", ["stiffness", "life"])
def test_a_double_press_of_the_chest_button_mid_trial_replays_the_turn_on_a_robot_set_back(tmp_path, standin, does):
    """Pressed twice at turn 1's beep, the stand-in raises ALChestButton/DoubleClickOccurred and removes its
    stiffness (alchestbutton.html) or switches Autonomous Life off and on (chest_button_usages.html): the turn is
    marked invalid and replayed, and before the replay's beep the session has set the robot back (motors woken,
    or life disabled again). Without the event the turn would be scored; without the upkeep, the replay would play
    on a limp (or autonomous) robot."""
    standin.control.set_chest_double(does)
    standin.control.act_after("ALAudioPlayer.playSine", "chest", [2])
    result = _play(_config(tmp_path, standin.url), RunOptions(quiet=True))
    assert result.status == "completed"
    folder = result.path
    rows = read_turns(folder)
    first = rows[0]
    assert first["invalid"] == "True" and "chest button double-clicked during the trial" in first["notes"]
    again = rows[1]
    assert again["action"] == first["action"] and again["success"] in ("True", "False") and not again.get("invalid")
    events = read_events(folder)
    health = [e for e in events if e["event"] == "robot_health"]
    assert [(e["kind"], e["turn"]) for e in health] == [("chest_double", 1)]
    assert "set back before the next turn" in health[0]["decision"]
    robot_commands = [e for e in events if e["event"] == "command" and e["source"] == "robot"]
    assert [(c["kind"], c["accepted"]) for c in robot_commands] == [("repeat", True)]
    calls = _calls(standin)
    pressed = calls.index(("NaoTrainerStandIn", "chest"))
    next_beep = calls.index(("ALAudioPlayer", "playSine"), pressed)
    set_back = ("ALMotion", "wakeUp") if does == "stiffness" else ("ALAutonomousLife", "setState")
    assert set_back in calls[pressed:next_beep]  # restored before the replayed turn's beep
    found = "motors_found_off" if does == "stiffness" else "autonomous_life_changed"
    replay_start = [e["mono"] for e in events if e["event"] == "turn_start"][1]
    assert [e["mono"] <= replay_start for e in events if e["event"] == found] == [True]
    assert sum(r["success"] in ("True", "False") for r in rows) == 3


def test_a_critically_hot_knee_makes_the_nao_sit_before_the_next_turn(tmp_path, standin):
    standin.control.act_after("ALAudioPlayer.playSine", "heat", ["LKneePitch", 3])
    result = _play(_config(tmp_path, standin.url), RunOptions(quiet=True))
    assert result.status == "completed"
    events = read_events(folder := next(tmp_path.glob("*_*")))
    cooling = [e for e in events if e["event"] == "cooling_posture"]
    assert len(cooling) == 1 and cooling[0]["joint"] == "LKneePitch" and cooling[0]["posture"] == "Sit"
    assert ("ALRobotPosture", "goToPosture") in [(c["service"], c["method"]) for c in standin.transcript()]
    refused = [e for e in events if e["event"] == "wake_up_failed"]
    assert refused  # the resting robot refused wakeUp: honoured, never logged as set back
    assert len(read_turns(folder)) == 3


def test_a_warm_knee_at_warning_is_named_for_the_operator_and_the_session_goes_on_standing(tmp_path, standin):
    standin.control.act_after("ALAudioPlayer.playSine", "heat", ["LKneePitch", 1])  # hot (status 1) during turn 1
    result = _play(_config(tmp_path, standin.url), RunOptions(quiet=True))
    assert result.status == "completed"
    events = read_events(folder := next(tmp_path.glob("*_*")))
    hot = [e for e in events if e["event"] == "robot_health" and e["kind"] == "hot"]
    assert [(e["severity"], e["part"]) for e in hot] == [("warning", "LKneePitch")]
    assert "LKneePitch" in hot[0]["detail"] and "let it sit between turns" in hot[0]["decision"]
    assert not [e for e in events if e["event"] in ("cooling_posture", "wake_up_failed")]  # suggested, not forced
    assert not [e for e in events if e["event"] == "command" and e.get("source") == "robot"]  # no pause, no replay
    postures = [c["args"] for c in standin.transcript() if (c["service"], c["method"]) == ("ALRobotPosture", "goToPosture")]
    assert all(args[0] != "Sit" for args in postures)
    assert len(read_turns(folder)) == 3


def test_a_session_in_french_sets_the_robots_voice_and_speaks_the_french_dialogue(tmp_path, standin):
    from nao_trainer.files import PROJECT_ROOT

    config = _config(tmp_path, standin.url, **{"session.language": "fr",
                                               "session.dialogue": str(PROJECT_ROOT / "dialogue" / "fr.yaml")})
    result = _play(config, RunOptions(quiet=True))
    assert result.status == "completed"
    calls = standin.transcript()
    set_language = [c["args"] for c in calls if c["method"] == "setLanguage"]
    assert set_language == [["French"]]
    first_say = next(i for i, c in enumerate(calls) if c["method"] == "say")
    assert calls.index(next(c for c in calls if c["method"] == "setLanguage")) < first_say  # set before speaking
    spoken = " ".join(str(c["args"][0]) for c in calls if c["method"] == "say")
    assert "Niveau" in spoken and "Level" not in spoken


def test_a_language_the_robot_lacks_or_a_dialogue_in_another_stops_the_start_in_one_line(tmp_path, standin):
    from nao_trainer.errors import ConfigError, RobotUnavailable
    from nao_trainer.files import PROJECT_ROOT

    standin.control.set_languages(["English"])
    config = _config(tmp_path, standin.url, **{"session.language": "fr",
                                               "session.dialogue": str(PROJECT_ROOT / "dialogue" / "fr.yaml")})
    with pytest.raises(RobotUnavailable, match=r"needs the robot's French voice, but it has only English"):
        _play(config, RunOptions(quiet=True))
    assert not list(tmp_path.glob("*_*"))  # nothing written
    with pytest.raises(ConfigError, match=r"dialogue language 'en' differs from session.language 'fr'"):
        _play(_config(tmp_path, standin.url, **{"session.language": "fr"}), RunOptions(quiet=True))


def test_a_refused_life_change_fails_check_and_the_start_unless_life_on_is_allowed(tmp_path, standin):
    from nao_trainer.errors import RobotUnavailable
    from nao_trainer.session.check import check_robot, plan_from_config

    standin.control.refuse_life(True)
    config = _config(tmp_path, standin.url)
    result = check_robot(plan_from_config(config))
    assert not result.ok and result.exit_code == 3 and "not currently allowed" in result.detail
    assert "getting-started wizard" in result.fix
    with pytest.raises(RobotUnavailable, match="refused to set Autonomous Life"):
        _play(config, RunOptions(quiet=True))
    allowed = _config(tmp_path, standin.url, **{"robot.allow_life_on": True})
    assert check_robot(plan_from_config(allowed)).ok
    assert _play(allowed, RunOptions(quiet=True)).status == "completed"


def test_check_says_whether_the_battery_and_the_joints_will_last_the_session(tmp_path, standin):
    from nao_trainer.session.check import check_robot, plan_from_config

    config = _config(tmp_path, standin.url, **{"session.turns": 60})
    result = check_robot(plan_from_config(config))
    assert result.ok and "battery 85% lasts ~51 min, the session needs ~25 min" in result.detail
    standin.control.set_battery(35)  # above the 30 % floor, below what 60 turns need
    low = check_robot(plan_from_config(config))
    assert not low.ok and "lasts ~21 min" in low.detail and "charge the robot first" in low.fix
    standin.control.set_battery(90)
    standin.control.heat("RKneePitch", 1)
    warm = check_robot(plan_from_config(config))
    assert not warm.ok and "hot joints now: RKneePitch (status 1)" in warm.detail and "let the robot cool" in warm.fix


def test_a_session_on_a_pepper_with_safeguard_mid_session(tmp_path):
    """Pepper over the same adapter (issue 27 item 4): the stand-in plays a Pepper 2.9 without ALLeds; the
    session says once that the eye colours are skipped, uses Pepper's postures, pauses while Autonomous Life is
    in safeguard (motors held) and plays on after the operator resumes."""
    pepper = StandIn.start(speed=50, model="pepper", without=("ALLeds",))
    try:
        pepper.control.act_after("ALAudioPlayer.playSine", "safeguard", [])
        commands, watcher = CommandQueue(), _Watcher()
        paused = watcher.when("pause", lambda d: d.get("paused"))

        def operator():
            if paused.wait(HANG_S):
                commands.submit("resume", source="test")

        threading.Thread(target=operator, daemon=True).start()
        config = _config(tmp_path, pepper.url, **{"robot.model": "pepper"})
        result = _play(config, RunOptions(quiet=True, commands=commands, observer=watcher))
        calls = pepper.transcript()
    finally:
        pepper.stop()
    assert result.status == "completed" and len([r for r in result.rows if r["success"] in (True, False)]) == 3
    import json
    events = read_events(result.path)
    setup = json.loads((result.path / "session.json").read_text())["robot_setup"]  # before the folder existed
    degraded = [e["detail"] for e in setup if e["event"] == "robot_degraded"]
    assert "Pepper offers no ALLeds: the eye colours of the behaviors file are not shown" in degraded
    assert any(e["event"] == "robot_health" and e["kind"] == "safeguard" for e in events)
    assert [e["event"] for e in events].count("motors_held") == 1
    postures = {c["args"][0] for c in calls if c["method"] == "goToPosture"}
    assert postures <= {"Stand", "StandInit", "StandZero", "Crouch"} and "Stand" in postures
    assert not [c for c in calls if c["service"] == "ALLeds"]


def test_mock_robot_plays_the_study_model(tmp_path):
    config = _config(tmp_path, "mock", **{"robot.model": "pepper"})
    result = _play(config, RunOptions(quiet=True))
    assert result.status == "completed"
    import json
    info = json.loads((result.path / "session.json").read_text())
    assert info["config"]["values"]["robot"]["model"] == "pepper"
    degraded = [e["detail"] for e in info["robot_setup"] if e["event"] == "robot_degraded"]
    assert degraded == ["Pepper offers no ALTracker: nothing: the task does not track faces (Pepper 2.9 has no ALTracker)"]


def test_a_stop_while_the_robot_is_away_ends_the_session_at_once(tmp_path):
    """The robot's link is gone (the stand-in stopped) and the study would try for 600 s: the operator's stop
    ends the attempts; the session ends stopped (exit 5), the interrupted turn recorded. Not honoured, the
    session sits out the 600 s and the hang limit fails the test."""
    from nao_trainer.session.engine import EXIT_OPERATOR_STOP

    robot = StandIn.start(speed=50)
    commands, watcher = CommandQueue(), _Watcher()
    lost = watcher.when("robot", lambda d: d.get("robot") == "lost")
    first = watcher.when("row", lambda d: d.get("success") in (True, False))

    def robot_goes():
        if first.wait(HANG_S):
            robot.stop()

    def operator():
        if lost.wait(HANG_S):
            commands.submit("stop", source="keys")

    threading.Thread(target=robot_goes, daemon=True).start()
    threading.Thread(target=operator, daemon=True).start()
    try:
        config = _config(tmp_path, robot.url, **{"session.turns": 6, "robot.max_reconnect_s": 600,
                                                 "robot.backoff_initial_s": 0.2, "robot.backoff_max_s": 1})
        result = _play(config, RunOptions(quiet=True, commands=commands, observer=watcher))
    finally:
        robot.stop()
    assert result.status == "stopped" and result.exit_code == EXIT_OPERATOR_STOP
    events = read_events(result.path)
    assert not any(e["event"] == "give_up" for e in events)
    stop = [e for e in events if e["event"] == "command" and e["kind"] == "stop"]
    assert len(stop) == 1 and stop[0]["accepted"] and stop[0]["state"] == "paused"
    assert any(e["event"] == "robot_lost" for e in events)


@pytest.mark.parametrize("go_on_while_away", [False, True])
def test_a_pause_while_the_robot_is_away_acts_at_once_and_holds_once_it_is_back(tmp_path, go_on_while_away):
    """The robot's link is gone (the stand-in stopped after turn 1) and the operator pauses: the pause is taken at
    once (recorded while the session is still reconnecting, before the robot is back). The robot comes back (a new
    stand-in on the same address): the session stays paused, no turn plays, until the operator goes on; then it
    replays the interrupted turn and completes. A go-on given while the robot is still away cancels the pause:
    the session plays on as soon as the robot is back. Not honoured, the pause would only be recorded once the
    robot is back, and the robot is brought back only after it is recorded: the hang limit fails the test."""
    first = StandIn.start(speed=50)
    url = first.url
    commands, watcher = CommandQueue(), _Watcher()
    lost = watcher.when("robot", lambda d: d.get("robot") == "lost")
    one_row = watcher.when("row", lambda d: d.get("success") in (True, False))
    paused_away = watcher.when("command", lambda d: d["kind"] == "pause" and d["accepted"] and d["state"] == "paused")
    went_on_away = watcher.when("command", lambda d: d["kind"] == "resume" and d["accepted"] and d["state"] == "paused")
    held = watcher.when("state", lambda d: d.get("state") == "operator_pause")
    back: list[StandIn] = []

    def robot_and_operator():
        if not one_row.wait(HANG_S):
            return
        first.stop()
        if not lost.wait(HANG_S):
            return
        commands.submit("pause", source="keys")
        if not paused_away.wait(HANG_S):
            return
        if go_on_while_away:
            commands.submit("resume", source="keys")
            if not went_on_away.wait(HANG_S):
                return
        back.append(StandIn.start(url, speed=50))  # the robot is back, on the same address
        if not go_on_while_away and held.wait(HANG_S):
            commands.submit("resume", source="keys")

    helper = threading.Thread(target=robot_and_operator, daemon=True)
    helper.start()
    try:
        config = _config(tmp_path, url, **{"session.turns": 3, "robot.max_reconnect_s": 120,
                                           "robot.backoff_initial_s": 0.1, "robot.backoff_max_s": 0.3})
        result = _play(config, RunOptions(quiet=True, commands=commands, observer=watcher))
        helper.join(HANG_S)
    finally:
        first.stop()
        for robot in back:
            robot.stop()
    assert back, "the pause was not taken while the robot was away"
    assert result.status == "completed" and result.exit_code == 0
    events = read_events(result.path)
    names = [e["event"] for e in events]
    ops = [(e["kind"], e["state"], e["accepted"]) for e in events if e["event"] == "command"]
    reconnected = names.index("reconnected")
    pause_at = next(i for i, e in enumerate(events) if e["event"] == "command" and e["kind"] == "pause")
    assert pause_at < reconnected  # taken while the robot was away
    holds = [e for e in events if e["event"] == "transition" and e["source"] == "paused" and e["trigger"] == "pause"]
    after_back = [e for e in events[reconnected:] if e["event"] == "turn_start"]
    if go_on_while_away:
        assert ops == [("pause", "paused", True), ("resume", "paused", True)] and not holds
        assert after_back  # played on once back
    else:
        assert ops == [("pause", "paused", True), ("resume", "operator_pause", True)] and len(holds) == 1
        resume_at = max(i for i, e in enumerate(events) if e["event"] == "command" and e["kind"] == "resume")
        assert [i for i, e in enumerate(events) if e["event"] == "turn_start" and i > reconnected][0] > resume_at
    rows = read_turns(result.path)
    interrupted = [r for r in rows if r["notes"].startswith("interrupted: robot lost")]
    assert len(interrupted) <= 1 and sum(r["success"] in ("True", "False") for r in rows) == 3
