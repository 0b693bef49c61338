"""Robot models as plug-ins (issue 26 item 6) and the robot's side of a session's health (issue 27 items 1, 2, 4),
over a real qi session with the stand-in playing the robot: the registry's models, their settings and
postures, the services probed (a missing optional one degrades in one line), the ALMemory health events as
they arrive, a refused ``ALAutonomousLife.setState``, a refused ``ALMotion.wakeUp``, and the speech language."""
from __future__ import annotations

import threading

import pytest

from nao_trainer import registry
from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.robot.health import HealthWatch, read_event
from nao_trainer.robot.lifecycle import TaskLife
from nao_trainer.cli import main
from nao_trainer.robot.model import default_model, make_model, model_called
from nao_trainer.robot.profile import Profile
from nao_trainer.robot.standin.body import Body
from nao_trainer.robot.standin.services import played
from nao_trainer.robot.naoqi import NaoqiRobot
from nao_trainer.robot.standin import StandIn
from nao_trainer.session.behaviors import load_behaviors
from nao_trainer.session.config import load_config
from nao_trainer.session.robot_setup import probe_model, set_language
from nao_trainer.session.wiring import check_postures
from tests._waits import HANG_S


def test_the_registry_names_nao_and_pepper_and_a_study_chooses_one_with_its_settings():
    assert {"nao", "pepper"} <= set(registry.names("robot_model"))
    config = load_config(None, {"robot.model": "pepper"})
    model = config.robot.robot_model()
    assert model.title == "Pepper" and "Sit" not in model.postures and model.cool_posture() is None
    nao = load_config(None, {}).robot.robot_model()
    assert nao.cool_posture() == "Sit" and nao.can("sit") and not model.can("sit")
    with pytest.raises(ConfigError, match=r"robot.model_settings.cool_posture' must be one of Crouch, Sit, SitRelax"):
        load_config(None, {"robot.model_settings": {"cool_posture": "Stand"}})
    with pytest.raises(ConfigError, match="unknown robot model 'pepperr' .did you mean 'pepper'"):
        load_config(None, {"robot.model": "pepperr"})


def test_the_robot_is_named_by_the_model_claiming_its_body_type_and_the_standin_says_what_it_plays(capsys):
    """Issue 26 (no kind string compared outside its registry): what a robot calls itself is asked of the
    models' ``type_names``, a robot built without a study is ``robot.model``'s default, and the stand-in says
    which models it has a body for (``--robot mock``, ``mock-robot --model``)."""
    assert (model_called("juliette"), model_called("nao"), model_called("romeo")) == ("pepper", "nao", None)
    body = Body()
    Profile(body_type="juliette").apply(body)
    assert body.model == "pepper"
    Profile(body_type="romeo").apply(body)
    assert body.model == "romeo"  # a robot no model claims keeps its own name
    assert default_model().name == registry.default("robot_model") == load_config(None, {}).robot.model == "nao"
    assert (played("pepper"), played("nao"), played("romeo")) == ("pepper", "nao", "nao")
    with pytest.raises(SystemExit) as exited:
        main(["mock-robot", "--model", "romeo"])
    assert exited.value.code == 2
    assert "argument --model: invalid choice: 'romeo' (choose from 'nao', 'pepper')" in capsys.readouterr().err


def test_the_behaviors_postures_must_exist_on_the_model(tmp_path):
    config = load_config(None, {"robot.model": "pepper", "robot.url": "tcp://127.0.0.1:9559"})
    check_postures(config, load_behaviors(config.session.behaviors_path))  # Stand / Crouch: Pepper has both
    sitting = tmp_path / "sit.yaml"
    default = (config.session.behaviors_path).read_text()
    sitting.write_text(default.replace("  end: Crouch ", "  end: Sit    ", 1))
    with pytest.raises(ConfigError, match=r"postures.end 'Sit' is not a posture of Pepper .*Stand, StandInit, StandZero, Crouch"):
        check_postures(config, load_behaviors(sitting))


class _Events:
    """Collects what the robot reports; ``wait(n)`` returns once ``n`` events came (a hang fails)."""

    def __init__(self) -> None:
        self.lines: list = []
        self._cond = threading.Condition()

    def __call__(self, name, **data):
        with self._cond:
            self.lines.append((name, data))
            self._cond.notify_all()


@pytest.fixture
def standin():
    s = StandIn.start(speed=50)
    yield s
    s.stop()


def _robot(url, model="nao"):
    return NaoqiRobot.connect(url, 10.0, buttons=make_model(model).buttons)


def _wait_pending(watch, n):
    got, cond = [], threading.Event()
    for _ in range(int(HANG_S / 0.05)):
        got += watch.pending()
        if len(got) >= n:
            return got
        cond.wait(0.05)
    raise AssertionError(f"only {len(got)} of {n} health events arrived: {got}")


def test_health_events_arrive_over_qi_as_the_model_declares_them(standin):
    robot = _robot(standin.url)
    watch = HealthWatch.start(robot, make_model("nao"))
    try:
        standin.control.fall()
        standin.control.heat("LKneePitch", 3)
        standin.control.battery_low()
        standin.control.chest(1)
        events = _wait_pending(watch, 5)
        assert sorted(e.kind for e in events) == ["battery_low", "chest", "fallen", "falling", "hot"]  # qi threads: any order
        (hot,) = [e for e in events if e.kind == "hot"]
        assert hot.severity == "critical" and hot.part == "LKneePitch" and "LKneePitch critically hot" in hot.detail
        assert standin.body()["motors_on"] is False and standin.body()["fallen"] is True
    finally:
        watch.close()
        robot.close()


def test_heat_values_of_either_guessed_shape_name_the_joint_and_its_level():
    warm = read_event("hot", ["RKneePitch"])
    assert (warm.severity, warm.part) == ("warning", "RKneePitch")
    worst = read_event("hot", [["LAnklePitch", 1], ["RHipPitch", 3]])
    assert (worst.severity, worst.part) == ("critical", "RHipPitch")
    assert read_event("safeguard", "solitary") is None and read_event("safeguard", "safeguard").severity == "critical"


def test_a_refused_set_state_stops_the_start_unless_the_study_allows_life_on(standin):
    standin.control.refuse_life(True)
    robot = _robot(standin.url)
    events = _Events()
    try:
        with pytest.raises(RobotUnavailable, match=r"refused to set Autonomous Life to 'disabled' .*not currently "
                                                   r"allowed.*getting-started wizard.*robot.allow_life_on: true"):
            TaskLife(robot, "disabled", report=events).enter()
        assert standin.body()["life"] == "solitary"
        life = TaskLife(robot, "disabled", report=events, allow_life_on=True)
        life.enter()  # goes on with life on, reported
        assert ("set_autonomous_life_failed" in [name for name, _ in events.lines]) and life.entered
    finally:
        robot.close()


def test_a_refused_wake_up_is_honoured_at_the_start_and_between_turns(standin):
    robot = _robot(standin.url)
    events = _Events()
    try:
        life = TaskLife(robot, "disabled", report=events)
        life.enter()
        assert robot.wake_up() is True
        standin.control.heat("LKneePitch", 3)  # critical: motors off, wakeUp answers False
        assert life.between_turns() == []  # found off, could not wake: not "set back", so no replay on a resting robot
        assert ("wake_up_failed", {"error": "the robot answered False (refused)"}) in events.lines
        assert robot.wake_up() is False
        with pytest.raises(RobotUnavailable, match="refused to wake up .*let it cool"):
            TaskLife(robot, "disabled", report=events).enter()
    finally:
        robot.close()


def test_held_motors_are_never_woken_between_turns(standin):
    robot = _robot(standin.url)
    try:
        life = TaskLife(robot, "disabled")
        life.enter()
        standin.control.fall()
        life.hold_motors("the robot has fallen")
        standin.clear()
        assert life.between_turns() == []
        assert not [c for c in standin.transcript() if c["method"] == "wakeUp"]
        life.hold_motors(None)
        assert life.between_turns() == ["motors off"]
    finally:
        robot.close()


def test_the_session_language_is_set_and_a_missing_voice_is_one_line_naming_the_installed_ones(standin):
    robot = _robot(standin.url)
    events = _Events()
    try:
        model = make_model("nao")
        set_language(robot, model, "fr", events)
        assert robot.call("ALTextToSpeech", "getLanguage") == "French"
        with pytest.raises(RobotUnavailable, match=r"session.language 'de' needs the robot's German voice, but it has "
                                                   r"only English, French: install German"):
            set_language(robot, model, "de", events)
    finally:
        robot.close()


def test_pepper_without_optional_services_degrades_in_one_line_each_and_a_nao_needs_them():
    standin = StandIn.start(speed=50, model="pepper", without=("ALLeds", "ALAnimatedSpeech"))
    try:
        robot = _robot(standin.url, "pepper")
        events = _Events()
        probe_model(robot, make_model("pepper"), True, events, None)
        lines = [data["detail"] for name, data in events.lines if name == "robot_degraded"]
        assert "Pepper offers no ALLeds: the eye colours of the behaviors file are not shown" in lines
        assert "Pepper offers no ALAnimatedSpeech: the robot speaks without gestures" in lines
        robot.say("hello", animated=True)  # plain speech instead
        robot.set_eye_leds(0x00FF00, 0.1)  # skipped
        said = [(c["service"], c["method"]) for c in standin.transcript()]
        assert ("ALTextToSpeech", "say") in said and ("ALLeds", "fadeRGB") not in said
        assert robot.call("ALRobotPosture", "getPostureList") == ["Stand", "StandInit", "StandZero", "Crouch"]
        with pytest.raises(RobotUnavailable, match=r"\(NAO\) offers no ALAnimatedSpeech, ALLeds service"):
            probe_model(robot, make_model("nao"), True, events, None)
        robot.close()
    finally:
        standin.stop()
