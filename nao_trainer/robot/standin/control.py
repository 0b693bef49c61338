"""The stand-in's control service (``NaoTrainerStandIn``, not NAOqi) and the assembly of all its services."""
from __future__ import annotations

import os
import threading
from typing import Any

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import ConfigError  # noqa: E402
from nao_trainer.robot.standin.body import (SLEEP_HOLD_S, STOP_ACTIVITY_HOLD_S, AudioDevice,  # noqa: E402
                                             AutonomousLife, Battery, Body, BodyTemperature, System,
                                             raises_battery_low)
from nao_trainer.robot.standin.recorder import Channel, Recorder, check_speed  # noqa: E402
from nao_trainer.robot.standin.services import (PRESS_HOLD_S, Memory, AnimatedSpeech, AudioPlayer,  # noqa: E402
                                                Leds, Motion, RobotPosture, TextToSpeech, button_key)

#: What a double click of the chest button may do (the two NAOqi 2.8 pages disagree: ``Control.chest``).
CHEST_DOUBLE = ("stiffness", "life")
#: How long (robot seconds) one press of the chest button is held: a guess to confirm with the conformance kit.
CHEST_PRESS_S = 0.05


@qi.multiThreaded()
class Control:
    """NaoTrainerStandIn: what tests and simulated participants use to act on the stand-in.

    Besides presses: a hand held on the head (``hold``), a bouncing contact (``bounce``), the
    battery level, latency of calls (through the link) and of the beep, and a frozen link.
    """

    def __init__(self, rec: Recorder, memory: Memory, body: Body, player: AudioPlayer) -> None:
        self._rec = rec
        self._memory = memory
        self._body = body
        self._player = player
        self.link: Any = None  # the stand-in's Link (latency, freeze), set by the server

    def _key(self, button: str) -> str:
        try:
            return button_key(button)
        except ValueError as exc:
            raise RuntimeError(str(exc)) from None

    def _touch(self, key: str) -> bool:
        """A touch reaches the task only when NAO is awake; asleep, a touch wakes it (sleep_nao.html)."""
        with self._body.lock:
            if not self._body.asleep:
                return True
            self._body.asleep, self._body.life, self._body.motors_on, self._body.posture = (
                False, "solitary", True, "Stand")
        return False

    @qi.bind(qi.String, [qi.String])
    def press(self, button: str) -> str:
        """Touch then release a head button; returns the ALMemory key pressed. The key is 1.0 then 0.0
        (http://doc.aldebaran.com/2-8/naoqi/sensors/altouch.html); the ``PRESS_HOLD_S`` between them is a guess to
        confirm with the conformance kit."""
        key = self._key(button)
        self._rec.record("NaoTrainerStandIn", "press", [key])
        if self._touch(key):
            self._memory.emit(key, 1.0)
            self._rec.wait(PRESS_HOLD_S)
            self._memory.emit(key, 0.0)
        return key

    @qi.bind(qi.String, [qi.String, qi.Float])
    def hold(self, button: str, seconds: float) -> str:
        """A hand on the head for ``seconds`` (robot time). With Autonomous Life on, 1 s stops the activity
        (http://doc.aldebaran.com/2-8/family/nao_user_guide/activity_nao.html) and 3 s puts NAO to sleep
        (http://doc.aldebaran.com/2-8/family/nao_user_guide/sleep_nao.html); that it then refuses speech and sound is a
        guess to confirm with the conformance kit. Returns the state after."""
        key = self._key(button)
        self._rec.record("NaoTrainerStandIn", "hold", [key, seconds])
        if self._touch(key):
            self._memory.emit(key, 1.0)
            self._rec.wait(seconds)
            self._memory.emit(key, 0.0)
            with self._body.lock:
                life_on = self._body.life in ("solitary", "interactive")
            if life_on and seconds >= SLEEP_HOLD_S:
                self._body.fall_asleep()
                return "asleep"
            if life_on and seconds >= STOP_ACTIVITY_HOLD_S:
                return "activity stopped"
        return "nothing"

    @qi.bind(qi.Void, [qi.String, qi.Int32])
    def bounce(self, button: str, contacts: int) -> None:
        """A worn sensor: ``contacts`` touches 5 ms apart (robot time), as one press may give; a guess (no page documents
        it) to confirm with the conformance kit."""
        key = self._key(button)
        self._rec.record("NaoTrainerStandIn", "bounce", [key, contacts])
        for _ in range(max(1, contacts)):
            self._memory.emit(key, 1.0)
            self._rec.wait(0.005)
            self._memory.emit(key, 0.0)
            self._rec.wait(0.005)

    @qi.bind(qi.Void, [qi.Int32])
    def set_battery(self, percent: int) -> None:
        """The charge (percent); a change raises ``BatteryChargeChanged`` with it
        (http://doc.aldebaran.com/2-8/naoqi/sensors/albattery-api.html)."""
        with self._body.lock:
            before, self._body.battery = self._body.battery, max(0, min(100, int(percent)))
            after = self._body.battery
        if after != before:
            self._memory.emit("BatteryChargeChanged", after)

    @qi.bind(qi.Void, [qi.Float, qi.Float])
    def set_latency(self, round_trip_s: float, beep_s: float) -> None:
        """Network round trip of every call (wall seconds) and the beep's audio latency (robot seconds)."""
        if self.link is not None:
            self.link.latency_s = max(0.0, float(round_trip_s))
        self._player.latency_s = max(0.0, float(beep_s))

    @qi.bind(qi.Void, [qi.Float])
    def freeze(self, seconds: float) -> None:
        """Freeze the link (alive, silent) for ``seconds`` of wall time, starting just after this reply."""
        self._rec.record("NaoTrainerStandIn", "freeze", [seconds])
        link = self.link
        if link is not None:
            threading.Timer(0.02, link.freeze, (float(seconds),)).start()

    @qi.bind(qi.Void, [qi.String, qi.Float])
    def freeze_after(self, call: str, seconds: float) -> None:
        """Freeze the link for ``seconds`` once the next ``call`` (only "ALAudioPlayer.playSine") has returned."""
        self._rec.record("NaoTrainerStandIn", "freeze_after", [call, seconds])
        link = self.link
        if link is not None:
            self._rec.arm(call, lambda: threading.Timer(0.02, link.freeze, (float(seconds),)).start())

    @qi.bind(qi.Void, [qi.String, qi.Float])
    def freeze_at(self, call: str, seconds: float) -> None:
        """Freeze the link for ``seconds`` as the next ``call`` finishes, before its reply is sent: the robot
        did it (the beep sounded), the laptop hears back late. A test hook, not NAOqi behaviour."""
        self._rec.record("NaoTrainerStandIn", "freeze_at", [call, seconds])
        link = self.link
        if link is not None:
            self._rec.arm(call, lambda: link.freeze(float(seconds)))

    @qi.bind(qi.Void, [qi.String, qi.String, qi.Float])
    def hold_after(self, call: str, button: str, seconds: float) -> None:
        """A hand held on the head for ``seconds`` (robot time), starting once the next ``call`` has
        returned (``Recorder.arm``: e.g. "ALAudioPlayer.playSine>speech"). Armed inside the stand-in, so
        the hold falls at a known point of the session however slow the machine is; its outcome is
        recorded in the transcript as ``held``."""
        key = self._key(button)
        self._rec.record("NaoTrainerStandIn", "hold_after", [call, key, seconds])

        def run() -> None:
            outcome = self.hold(button, seconds)
            self._rec.record("NaoTrainerStandIn", "held", [key, outcome])

        self._rec.arm(call, lambda: threading.Thread(target=run, name="standin-hold", daemon=True).start())

    @qi.bind(qi.String, [qi.Int32])
    def chest(self, clicks: int) -> str:
        """Clicks of the chest button; returns what the robot did.

        Events (http://doc.aldebaran.com/2-8/naoqi/sensors/alchestbutton-api.html): each press raises
        ``ChestButtonPressed`` 1.0, then ``ALChestButton/SimpleClickOccurred``, ``ALChestButton/DoubleClickOccurred``
        or ``ALChestButton/TripleClickOccurred`` for one, two or three clicks. That a release raises
        ``ChestButtonPressed`` 0.0, and that a double click raises no simple click first, are guesses to confirm with the
        conformance kit.

        What the robot does: the two NAOqi 2.8 pages disagree on a double click. The stand-in follows
        http://doc.aldebaran.com/2-8/naoqi/sensors/alchestbutton.html ("At double click, the stiffness is removed":
        the motors go off, the posture unchanged); http://doc.aldebaran.com/2-8/family/nao_user_guide/chest_button_usages.html
        says "Press twice: set the life off and on" instead, played after ``set_chest_double("life")``; which one a
        NAO does is a guess to confirm with the conformance kit. A simple click makes NAO say its name and address
        (alchestbutton.html); the stand-in says nothing (a guess: it speaks over the task on a robot)."""
        self._rec.record("NaoTrainerStandIn", "chest", [clicks])
        for _ in range(max(0, int(clicks))):
            self._memory.emit("ChestButtonPressed", 1.0)
            self._rec.wait(CHEST_PRESS_S)
            self._memory.emit("ChestButtonPressed", 0.0)
        if clicks == 2:
            with self._body.lock:
                does = self._body.chest_double
                if does == "life":  # off and on: life on from disabled (the robot stands), else off
                    self._body.life = "solitary" if self._body.life == "disabled" else "disabled"
                    if self._body.life == "solitary":
                        self._body.motors_on, self._body.posture = True, "Stand"
                else:
                    self._body.motors_on = False
            self._memory.emit("ALChestButton/DoubleClickOccurred", True)
            return "life switched off and on" if does == "life" else "stiffness removed"
        if clicks == 1:
            self._memory.emit("ALChestButton/SimpleClickOccurred", True)
            return "name and address"
        if clicks == 3:
            self._memory.emit("ALChestButton/TripleClickOccurred", True)
        return "nothing"

    @qi.bind(qi.Void, [qi.String])
    def set_chest_double(self, does: str) -> None:
        """What a double click of the chest button does from now on: "stiffness" (the default, following
        http://doc.aldebaran.com/2-8/naoqi/sensors/alchestbutton.html) or "life" (off and on, following
        http://doc.aldebaran.com/2-8/family/nao_user_guide/chest_button_usages.html); either is a guess until the
        conformance kit settles it."""
        if does not in CHEST_DOUBLE:
            raise RuntimeError(f"set_chest_double: {does!r} is not one of {', '.join(CHEST_DOUBLE)}")
        with self._body.lock:
            self._body.chest_double = does

    @qi.bind(qi.Void, [qi.String, qi.Int32])
    def chest_after(self, call: str, clicks: int) -> None:
        """``chest(clicks)`` once the next ``call`` has returned (a known point of a session)."""
        self._rec.record("NaoTrainerStandIn", "chest_after", [call, clicks])
        self._rec.arm(call, lambda: threading.Thread(target=self.chest, args=(int(clicks),), name="standin-chest",
                                                     daemon=True).start())

    # -- the robot's health (robot.health watches these events) -----------------------------------

    @qi.bind(qi.Void, [])
    def fall(self) -> None:
        """The fall manager: ``ALMotion/RobotIsFalling``, stiffness off, ``robotHasFallen``
        (http://doc.aldebaran.com/2-8/naoqi/motion/reflexes-fall-manager.html); lying on its belly afterwards is a guess
        to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "fall", [])
        self._memory.emit("ALMotion/RobotIsFalling", True)
        with self._body.lock:
            self._body.motors_on, self._body.posture, self._body.fallen = False, "LyingBelly", True
        self._memory.emit("robotHasFallen", True)

    @qi.bind(qi.Void, [])
    def stand_up(self) -> None:
        """Someone stood the robot up (motors still off: ``wakeUp`` is the session's to call); crouching with the motors
        off is a guess to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "stand_up", [])
        with self._body.lock:
            self._body.posture, self._body.fallen = "Crouch", False

    @qi.bind(qi.Void, [qi.String, qi.Int32])
    def heat(self, joint: str, status: int) -> None:
        """``joint``'s temperature status (0 normal .. 3 critical) in
        ``Device/SubDeviceList/<joint>/Temperature/Sensor/Status`` and ``HotDeviceDetected``
        (http://doc.aldebaran.com/2-8/naoqi/sensors/albodytemperature.html); at 3 the motors go off and ``wakeUp``
        answers False until it cools (http://doc.aldebaran.com/2-8/naoqi/motion/reflexes-diagnosis.html). The value's
        shape ``[[joint, status]]`` is a guess to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "heat", [joint, status])
        status = max(0, min(3, int(status)))
        with self._body.lock:
            if status:
                self._body.hot[joint] = status
            else:
                self._body.hot.pop(joint, None)
            if status >= 3:
                self._body.motors_on = False
        self._memory.emit(f"Device/SubDeviceList/{joint}/Temperature/Sensor/Status", status)
        if status:
            self._memory.emit("HotDeviceDetected", [[joint, status]])

    @qi.bind(qi.Void, [qi.String, qi.Float])
    def warm(self, joint: str, celsius: float) -> None:
        """``joint``'s temperature in °C (``Device/SubDeviceList/<joint>/Temperature/Sensor/Value``,
        http://doc.aldebaran.com/2-8/family/nao_technical/lola/actuator_sensor_names.html), its status unchanged (set
        that with ``heat``); that the two move independently is a guess to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "warm", [joint, celsius])
        with self._body.lock:
            self._body.temperatures[str(joint)] = float(celsius)

    @qi.bind(qi.Void, [])
    def battery_low(self) -> None:
        """The battery runs low: the charge drops to 10 % (``BatteryChargeChanged`` 10, "raised when the battery level
        percentage changes", http://doc.aldebaran.com/2-8/naoqi/sensors/albattery-api.html) and, on a NAOqi older than
        2.8.6, ``ALBattery/BatteryLow`` True. The 2.8 documentation lists ``ALBattery/BatteryLow`` among the events
        removed in 2.8.6 (http://doc.aldebaran.com/2-8/news/2.8/whatsnew2.8.6.html), its description comes from the
        2.5 pages, and http://doc.aldebaran.com/2-8/naoqi/sensors/albattery.html still names "a BatteryLow
        notification": that a 2.8.5 NAO raises it, and with True, is a guess to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "battery_low", [])
        with self._body.lock:
            self._body.battery = min(self._body.battery, 10)
            charge, raises = self._body.battery, raises_battery_low(self._body.version)
        self._memory.emit("BatteryChargeChanged", charge)
        if raises:
            self._memory.emit("ALBattery/BatteryLow", True)

    @qi.bind(qi.Void, [])
    def safeguard(self) -> None:
        """Pepper's Autonomous Life goes to ``safeguard``, a state of
        http://doc.aldebaran.com/2-8/naoqi/interaction/autonomouslife-api.html; raising ``AutonomousLife/State`` with it
        is a guess to confirm with the conformance kit."""
        self._rec.record("NaoTrainerStandIn", "safeguard", [])
        with self._body.lock:
            self._body.life = "safeguard"
        self._memory.emit("AutonomousLife/State", "safeguard")

    @qi.bind(qi.Void, [qi.Bool])
    def refuse_life(self, refused: bool) -> None:
        """``ALAutonomousLife.setState`` refused ("not currently allowed") while True: seen on robots whose getting-started
        wizard was not finished, undocumented, a guess to confirm with the conformance kit."""
        with self._body.lock:
            self._body.life_refused = bool(refused)

    @qi.bind(qi.Void, [qi.List(qi.String)])
    def set_languages(self, languages: list[str]) -> None:
        """The speech languages installed (what ``ALTextToSpeech.getAvailableLanguages`` answers,
        http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); a lab's robot's list is a guess until the
        conformance kit records it."""
        with self._body.lock:
            self._body.languages = [str(x) for x in languages]

    @qi.bind(qi.Void, [qi.String, qi.String, qi.List(qi.Dynamic)])
    def act_after(self, call: str, action: str, args: list[Any]) -> None:
        """Run ``action(*args)`` (fall, heat, battery_low, chest, safeguard, stand_up) once the next ``call`` has
        returned (``Recorder.arm``), so it falls at a known point of a session however slow the machine is."""
        actions = {"fall": self.fall, "heat": self.heat, "battery_low": self.battery_low, "chest": self.chest,
                   "safeguard": self.safeguard, "stand_up": self.stand_up}
        if action not in actions:
            raise RuntimeError(f"act_after: unknown action {action!r} (known: {', '.join(actions)})")
        self._rec.record("NaoTrainerStandIn", "act_after", [call, action, list(args)])
        self._rec.arm(call, lambda: threading.Thread(target=actions[action], args=tuple(args), name="standin-act",
                                                     daemon=True).start())

    @qi.bind(qi.Map(qi.String, qi.Dynamic), [])
    def body(self) -> dict[str, Any]:
        """The robot's state as tests read it: life, motors_on, posture, asleep, volume, muted, battery."""
        b = self._body
        with b.lock:
            return {"life": b.life, "motors_on": b.motors_on, "posture": b.posture, "asleep": b.asleep,
                    "volume": b.volume, "muted": b.muted, "battery": b.battery, "fallen": b.fallen,
                    "hot": dict(b.hot), "model": b.model, "languages": list(b.languages)}

    @qi.bind(qi.List(qi.Map(qi.String, qi.Dynamic)), [])
    def transcript(self) -> list[dict[str, Any]]:
        return self._rec.snapshot()

    @qi.bind(qi.Void, [])
    def clear(self) -> None:
        self._rec.clear()

    @qi.bind(qi.Void, [qi.Float])
    def set_speed(self, speed: float) -> None:
        try:
            self._rec.speed = check_speed(speed)
        except ConfigError as exc:
            raise RuntimeError(str(exc)) from None

    @qi.bind(qi.Float, [])
    def speed(self) -> float:
        return self._rec.speed


def build_services(rec: Recorder, body: Body | None = None,
                   without: tuple[str, ...] = ()) -> tuple[dict[str, Any], Memory, Control]:
    """One stand-in's services by the names a NAO offers them under (+ the control service); ``without``:
    NAOqi services this robot lacks (a Pepper 2.9 without some of NAO's)."""
    body = body or Body()
    memory = Memory(rec, body)
    player = AudioPlayer(rec, body)
    control = Control(rec, memory, body, player)
    speech = Channel(rec)  # say and animated say share one voice: stopAll cuts both
    services = {
        "ALTextToSpeech": TextToSpeech(rec, speech, body),
        "ALAnimatedSpeech": AnimatedSpeech(rec, speech, body),
        "ALAudioPlayer": player,
        "ALLeds": Leds(rec),
        "ALRobotPosture": RobotPosture(rec, body),
        "ALMotion": Motion(rec, body),
        "ALMemory": memory,
        "ALAutonomousLife": AutonomousLife(rec, body),
        "ALAudioDevice": AudioDevice(rec, body),
        "ALBattery": Battery(body),
        "ALSystem": System(body),
        "ALBodyTemperature": BodyTemperature(body),
        "NaoTrainerStandIn": control,
    }
    for name in without:
        if name == "NaoTrainerStandIn" or name not in services:
            raise ConfigError(f"the stand-in cannot go without {name!r}: it serves {', '.join(sorted(services))}")
        del services[name]
    return services, memory, control
