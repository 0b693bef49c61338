"""The NAOqi services of the stand-in (qi objects): speech, sound, LEDs, posture, motion, memory.

Each service records its calls in the stand-in's :class:`~nao_trainer.robot.standin.recorder.Recorder`
and takes robot time (scaled by the speed factor) where a NAO would.
"""
from __future__ import annotations

import os
import re
import threading
from typing import Any

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.ports import BUTTON_LETTERS  # noqa: E402
from nao_trainer.robot.standin.body import JOINT_C, NAOQI_VERSION, Body, raises_battery_low  # noqa: E402
from nao_trainer.robot.standin.recorder import Channel, Recorder  # noqa: E402

#: Speaking time per character at speed 1.0 (a NAO speaks roughly 12-15 characters a second).
SECONDS_PER_CHARACTER = 0.06
#: Time a posture change takes at speed 1.0 and posture speed 1.0.
POSTURE_SECONDS = 1.5
#: Postures ALRobotPosture knows on a NAO (naoqi/motion/alrobotposture.html), and on a Pepper.
POSTURES = ("Stand", "StandInit", "StandZero", "Crouch", "Sit", "SitRelax", "LyingBelly", "LyingBack")
MODEL_POSTURES = {"nao": POSTURES, "pepper": ("Stand", "StandInit", "StandZero", "Crouch")}
#: What ALMemory's ``RobotConfig/Body/Type`` says per model (a guess to confirm with the kit; Pepper's
#: internal name is "juliette").
BODY_TYPES = {"nao": "nao", "pepper": "juliette"}
#: ALAnimatedSpeech body language modes.
BODY_LANGUAGE_MODES = ("disabled", "random", "contextual")
#: How long a simulated finger stays on a head button (seconds, at speed 1.0).
PRESS_HOLD_S = 0.05

_LETTER_BUTTONS = {letter: key for key, letter in BUTTON_LETTERS.items()}


def can_play(model: str) -> bool:
    """Whether the stand-in has a body for the robot model ``model`` (its postures and body type)."""
    return model in MODEL_POSTURES


def played(model: str) -> str:
    """The robot the stand-in plays for ``model``: that model when it has its body, else a NAO."""
    return model if can_play(model) else "nao"



@qi.multiThreaded()
class TextToSpeech:
    """ALTextToSpeech: ``say`` blocks for a time proportional to the text."""

    def __init__(self, rec: Recorder, speech: Channel, body: Body) -> None:
        self._rec = rec
        self._speech = speech
        self._body = body
        self._lock = threading.Lock()
        self._language = body.languages[0] if body.languages else "English"
        self._params: dict[str, float] = {"speed": 100.0, "pitchShift": 1.0, "volume": 1.0}
        self._volume = 1.0
        #: Robot seconds per character spoken (a guess; a conformance profile sets the measured one).
        self.seconds_per_character = SECONDS_PER_CHARACTER

    @qi.bind(qi.Void, qi.AnyArguments)
    def say(self, *args: Any) -> None:
        """``say(text)`` or ``say(text, language)``, both overloads
        (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html).

        Guesses to confirm with the conformance kit: the call blocks for ``seconds_per_character`` per character
        (``hardware-check --record`` measures a robot's), and it is refused while NAO sleeps."""
        if len(args) not in (1, 2) or not all(isinstance(a, str) for a in args):
            raise RuntimeError("ALTextToSpeech::say expects (text) or (text, language)")
        self._rec.record("ALTextToSpeech", "say", list(args))
        self._body.check_awake("ALTextToSpeech::say")
        self._speech.run(self.seconds_per_character * len(args[0]))
        self._rec.finished("ALTextToSpeech.say")
        self._rec.finished("speech")

    @qi.bind(qi.Void, [qi.String])
    def setLanguage(self, language: str) -> None:
        """Set the speech language (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); refusing a language
        that is not installed is a guess to confirm with the conformance kit."""
        self._rec.record("ALTextToSpeech", "setLanguage", [language])
        with self._body.lock:
            installed = list(self._body.languages)
        if language not in installed:  # modelled: a language not installed is refused (confirm with the kit)
            raise RuntimeError(f"ALTextToSpeech::setLanguage: language {language!r} is not installed "
                               f"(installed: {', '.join(installed)})")
        with self._lock:
            self._language = language

    @qi.bind(qi.String, [])
    def getLanguage(self) -> str:
        """The current speech language (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html)."""
        with self._lock:
            return self._language

    @qi.bind(qi.List(qi.String), [])
    def getAvailableLanguages(self) -> list[str]:
        """The installed speech languages (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); which ones a
        robot has is a guess (``Body.languages``) to confirm with the conformance kit."""
        with self._body.lock:
            return list(self._body.languages)

    @qi.bind(qi.Void, [qi.String, qi.Float])
    def setParameter(self, name: str, value: float) -> None:
        """Set a speech parameter such as ``speed`` or ``pitchShift``
        (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); accepting any name is a guess to confirm
        with the conformance kit."""
        self._rec.record("ALTextToSpeech", "setParameter", [name, value])
        with self._lock:
            self._params[name] = float(value)

    @qi.bind(qi.Float, [qi.String])
    def getParameter(self, name: str) -> float:
        """A speech parameter (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); refusing an unknown name
        is a guess to confirm with the conformance kit."""
        with self._lock:
            if name not in self._params:
                raise RuntimeError(f"ALTextToSpeech::getParameter: unknown parameter {name!r}")
            return self._params[name]

    @qi.bind(qi.Void, [qi.Float])
    def setVolume(self, volume: float) -> None:
        """The speech engine's volume 0..1 (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html)."""
        self._rec.record("ALTextToSpeech", "setVolume", [volume])
        with self._lock:
            self._volume = float(volume)

    @qi.bind(qi.Float, [])
    def getVolume(self) -> float:
        """The speech engine's volume 0..1 (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html)."""
        with self._lock:
            return self._volume

    @qi.bind(qi.Void, [])
    def stopAll(self) -> None:
        """Interrupt the speech in progress (http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html); that it
        stops animated speech too is a guess to confirm with the conformance kit."""
        self._rec.record("ALTextToSpeech", "stopAll", [])
        self._speech.interrupt()


@qi.multiThreaded()
class AnimatedSpeech:
    """ALAnimatedSpeech: ``say(text)`` and ``say(text, configuration)`` (a NAOqi overload)."""

    def __init__(self, rec: Recorder, speech: Channel, body: Body) -> None:
        self._rec = rec
        self._speech = speech
        self._body = body
        self.seconds_per_character = SECONDS_PER_CHARACTER

    @qi.bind(qi.Void, qi.AnyArguments)
    def say(self, *args: Any) -> None:
        """``say(text)`` or ``say(text, configuration)`` with ``bodyLanguageMode``
        (http://doc.aldebaran.com/2-8/naoqi/audio/alanimatedspeech-api.html).

        Guesses to confirm with the conformance kit: the time per character spoken (annotations are not spoken), and the
        refusal while NAO sleeps."""
        if len(args) not in (1, 2) or not isinstance(args[0], str):
            raise RuntimeError("ALAnimatedSpeech::say expects (text) or (text, configuration)")
        if len(args) == 2:
            config = args[1]
            if not isinstance(config, dict):
                raise RuntimeError("ALAnimatedSpeech::say: configuration must be a map, e.g. {'bodyLanguageMode': 'contextual'}")
            mode = config.get("bodyLanguageMode", "contextual")
            if mode not in BODY_LANGUAGE_MODES:
                raise RuntimeError(
                    f"ALAnimatedSpeech::say: bodyLanguageMode must be one of {', '.join(BODY_LANGUAGE_MODES)}, got {mode!r}"
                )
        self._rec.record("ALAnimatedSpeech", "say", list(args))
        self._body.check_awake("ALAnimatedSpeech::say")
        self._speech.run(self.seconds_per_character * len(_strip_annotations(args[0])))
        self._rec.finished("ALAnimatedSpeech.say")
        self._rec.finished("speech")


def _strip_annotations(text: str) -> str:
    """Animated speech tags like ``^start(animations/...)`` or ``\\pau=300\\`` are not spoken."""
    return re.sub(r"\^\w+\([^)]*\)|\\\w+=\w+\\", "", text)


@qi.multiThreaded()
class AudioPlayer:
    """ALAudioPlayer: ``playSine`` blocks for the audio latency, then the beep's duration.

    ``latency_s`` (robot seconds, scaled by the speed factor) models the time from the call's
    arrival to the first sample out of the loudspeaker; a NAO's is not documented.
    """

    def __init__(self, rec: Recorder, body: Body) -> None:
        self._rec = rec
        self._body = body
        self._sound = Channel(rec)
        self.latency_s = 0.0

    @qi.bind(qi.Void, [qi.Int32, qi.Int32, qi.Int32, qi.Float])
    def playSine(self, frequency: int, gain: int, pan: int, duration: float) -> None:
        """``playSine(frequency, gain, pan, duration)`` (http://doc.aldebaran.com/2-8/naoqi/audio/alaudioplayer-api.html);
        gain in percent, pan -1/0/1 as the page gives them.

        Guesses to confirm with the conformance kit: the call blocks for ``latency_s`` then the tone's duration
        (``hardware-check --record`` measures both), and it is refused while NAO sleeps."""
        if not 0 <= gain <= 100:
            raise RuntimeError(f"ALAudioPlayer::playSine: gain must be 0..100 percent, got {gain}")
        if not -1 <= pan <= 1:
            raise RuntimeError(f"ALAudioPlayer::playSine: pan must be -1, 0 or 1, got {pan}")
        self._rec.record("ALAudioPlayer", "playSine", [frequency, gain, pan, duration])
        self._body.check_awake("ALAudioPlayer::playSine")
        if self._sound.run(self.latency_s):
            self._sound.run(duration)
        self._rec.finished("ALAudioPlayer.playSine")

    @qi.bind(qi.Void, [])
    def stopAll(self) -> None:
        """Stop every sound playing (http://doc.aldebaran.com/2-8/naoqi/audio/alaudioplayer-api.html)."""
        self._rec.record("ALAudioPlayer", "stopAll", [])
        self._sound.interrupt()


@qi.multiThreaded()
class Leds:
    """ALLeds: ``fadeRGB(name, 0xRRGGBB, secs)`` and ``fadeRGB(name, r, g, b, secs)`` block for ``secs``."""

    def __init__(self, rec: Recorder) -> None:
        self._rec = rec

    @qi.bind(qi.Void, qi.AnyArguments)
    def fadeRGB(self, *args: Any) -> None:
        """``fadeRGB(name, rgb, duration)`` and ``fadeRGB(name, r, g, b, duration)``
        (http://doc.aldebaran.com/2-8/naoqi/sensors/alleds-api.html); blocking for ``duration`` is a guess to confirm
        with the conformance kit."""
        if len(args) == 3:
            name, rgb, secs = args
            if not isinstance(rgb, int) or not 0 <= rgb <= 0xFFFFFF:
                raise RuntimeError(f"ALLeds::fadeRGB: rgb must be an int 0xRRGGBB, got {rgb!r}")
        elif len(args) == 5:
            name, *colour, secs = args
            if not all(isinstance(c, (int, float)) and 0.0 <= c <= 1.0 for c in colour):
                raise RuntimeError(f"ALLeds::fadeRGB: r, g, b must be floats in 0..1, got {colour!r}")
        else:
            raise RuntimeError("ALLeds::fadeRGB expects (name, rgb, secs) or (name, r, g, b, secs)")
        if not isinstance(name, str):
            raise RuntimeError(f"ALLeds::fadeRGB: LED name must be a string, got {name!r}")
        self._rec.record("ALLeds", "fadeRGB", list(args))
        self._rec.wait(float(secs))

    @qi.bind(qi.Void, [qi.String])
    def reset(self, name: str) -> None:
        """Reset an LED group to its default (http://doc.aldebaran.com/2-8/naoqi/sensors/alleds-api.html); the stand-in
        only records it."""
        self._rec.record("ALLeds", "reset", [name])

    @qi.bind(qi.Void, [qi.String])
    def on(self, name: str) -> None:
        """Switch an LED group on (http://doc.aldebaran.com/2-8/naoqi/sensors/alleds-api.html); the stand-in only records
        it."""
        self._rec.record("ALLeds", "on", [name])

    @qi.bind(qi.Void, [qi.String])
    def off(self, name: str) -> None:
        """Switch an LED group off (http://doc.aldebaran.com/2-8/naoqi/sensors/alleds-api.html); the stand-in only records
        it."""
        self._rec.record("ALLeds", "off", [name])


@qi.multiThreaded()
class RobotPosture:
    """ALRobotPosture: ``goToPosture`` takes time inversely proportional to the speed argument."""

    def __init__(self, rec: Recorder, body: Body) -> None:
        self._rec = rec
        self._body = body

    @qi.bind(qi.Bool, [qi.String, qi.Float])
    def goToPosture(self, name: str, speed: float) -> bool:
        """Go to a predefined posture; True when it is reached
        (http://doc.aldebaran.com/2-8/naoqi/motion/alrobotposture-api.html).

        Guesses to confirm with the conformance kit: it takes ``POSTURE_SECONDS / speed``, and with the motors off it
        answers False and the posture does not change."""
        self._rec.record("ALRobotPosture", "goToPosture", [name, speed])
        known = MODEL_POSTURES.get(self._body.model, POSTURES)
        if name not in known:
            raise RuntimeError(f"ALRobotPosture::goToPosture: unknown posture {name!r} (known: {', '.join(known)})")
        if not 0.0 < speed <= 1.0:
            raise RuntimeError(f"ALRobotPosture::goToPosture: speed must be in (0, 1], got {speed}")
        with self._body.lock:
            motors_on = self._body.motors_on
        if not motors_on:  # joints without stiffness do not move: the posture is not reached
            return False
        self._rec.wait(POSTURE_SECONDS / speed)
        with self._body.lock:
            self._body.posture = name
        return True

    @qi.bind(qi.String, [])
    def getPosture(self) -> str:
        """The current posture's name (http://doc.aldebaran.com/2-8/naoqi/motion/alrobotposture-api.html)."""
        with self._body.lock:
            return self._body.posture

    @qi.bind(qi.List(qi.String), [])
    def getPostureList(self) -> list[str]:
        """The predefined postures (http://doc.aldebaran.com/2-8/naoqi/motion/alrobotposture-api.html); Pepper's list is a
        guess to confirm with the conformance kit."""
        return list(MODEL_POSTURES.get(self._body.model, POSTURES))


@qi.multiThreaded()
class Motion:
    """ALMotion (subset): ``wakeUp`` sets the motors on and stands, ``rest`` crouches and sets them off."""

    def __init__(self, rec: Recorder, body: Body) -> None:
        self._rec = rec
        self._body = body

    @qi.bind(qi.Bool, [])
    def wakeUp(self) -> bool:
        """True if the call succeeded (http://doc.aldebaran.com/2-8/naoqi/motion/control-stiffness-api.html); False while a
        joint is critically hot, as the robot rests (http://doc.aldebaran.com/2-8/naoqi/motion/reflexes-diagnosis.html).
        Taking ``POSTURE_SECONDS`` is a guess to confirm with the conformance kit."""
        self._rec.record("ALMotion", "wakeUp", [])
        with self._body.lock:
            if any(status >= 3 for status in self._body.hot.values()):
                return False
            already = self._body.motors_on
            self._body.asleep = False
        if already:  # "if the robot is already stiffened, the call returns immediately"
            return True
        self._rec.wait(POSTURE_SECONDS)
        with self._body.lock:
            self._body.motors_on, self._body.fallen = True, False
            if self._body.posture not in ("LyingBelly", "LyingBack"):
                self._body.posture = "Stand"
        return True

    @qi.bind(qi.Void, [])
    def rest(self) -> None:
        """Go to a safe crouch and set the motors off
        (http://doc.aldebaran.com/2-8/naoqi/motion/control-stiffness-api.html); taking ``POSTURE_SECONDS`` is a guess to
        confirm with the conformance kit."""
        self._rec.record("ALMotion", "rest", [])
        self._rec.wait(POSTURE_SECONDS)
        with self._body.lock:
            self._body.motors_on, self._body.posture = False, "Crouch"

    @qi.bind(qi.Bool, [])
    def robotIsWakeUp(self) -> bool:
        """Whether the motors are on (http://doc.aldebaran.com/2-8/naoqi/motion/control-stiffness-api.html)."""
        with self._body.lock:
            return self._body.motors_on


class _MemorySubscriber:
    """What ``ALMemory.subscriber(key)`` returns: an object whose ``signal`` fires on each new value."""

    def __init__(self) -> None:
        self.signal = qi.Signal("m")


@qi.multiThreaded()
class Memory:
    """ALMemory (subset): key-value data and events; subscribers of a key get every raised value."""

    def __init__(self, rec: Recorder, body: Body | None = None) -> None:
        self._rec = rec
        self._body = body
        self._lock = threading.Lock()
        self._data: dict[str, Any] = {key: 0.0 for key in BUTTON_LETTERS}
        model = body.model if body is not None else "nao"
        self._data["RobotConfig/Body/Type"] = BODY_TYPES.get(model, model)
        self._subscribers: dict[str, list[_MemorySubscriber]] = {}

    @qi.bind(qi.Object, [qi.String])
    def subscriber(self, key: str) -> _MemorySubscriber:
        """A subscriber whose ``signal`` fires on each value raised for ``key``
        (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html)."""
        self._rec.record("ALMemory", "subscriber", [key])
        sub = _MemorySubscriber()
        with self._lock:
            self._subscribers.setdefault(key, []).append(sub)
        return sub

    @qi.bind(qi.Void, [qi.String, qi.Dynamic])
    def raiseEvent(self, key: str, value: Any) -> None:
        """Raise an event: the value is stored and subscribers are notified
        (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html)."""
        self._rec.record("ALMemory", "raiseEvent", [key, value])
        self.emit(key, value)

    @qi.bind(qi.Void, [qi.String, qi.Dynamic])
    def insertData(self, key: str, value: Any) -> None:
        """Store a value (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html); that it notifies the key's
        subscribers too is a guess to confirm with the conformance kit."""
        self._rec.record("ALMemory", "insertData", [key, value])
        self.emit(key, value)

    @qi.bind(qi.Dynamic, [qi.String])
    def getData(self, key: str) -> Any:
        """The value stored for ``key`` (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html); the wording of the
        error for a missing key is a guess. A joint's ``Device/SubDeviceList/<joint>/Temperature/Sensor/Value`` (°C,
        http://doc.aldebaran.com/2-8/family/nao_technical/lola/actuator_sensor_names.html) is always there: the one
        ``Control.warm`` set, else ``body.JOINT_C`` (a guess)."""
        with self._lock:
            if key in self._data:
                return self._data[key]
        joint = _temperature_joint(key)
        if joint is not None:
            with (self._body.lock if self._body is not None else self._lock):
                temps = self._body.temperatures if self._body is not None else {}
                return float(temps.get(joint, JOINT_C))
        raise RuntimeError(f"ALMemory::getData: there is no data for key {key!r}")

    @qi.bind(qi.List(qi.String), [])
    def getEventList(self) -> list[str]:
        """The declared events (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html: "a list containing the names
        of all the declared events"): those the stand-in raises (``EVENTS``), without ``ALBattery/BatteryLow`` on a
        NAOqi of 2.8.6 or later (``Control.battery_low``). That a NAO declares each event it raises is a guess to
        confirm with the conformance kit."""
        version = self._body.version if self._body is not None else NAOQI_VERSION
        silent = self._body.silent_events if self._body is not None else set()
        return sorted(e for e in EVENTS if e not in silent and (e != "ALBattery/BatteryLow" or raises_battery_low(version)))

    @qi.bind(qi.List(qi.String), [])
    def getDataListName(self) -> list[str]:
        """The names of the stored keys (http://doc.aldebaran.com/2-8/naoqi/core/almemory-api.html)."""
        with self._lock:
            return sorted(self._data)

    @qi.nobind  # the stand-in's own control service raises touches through it; not an ALMemory method
    def emit(self, key: str, value: Any) -> None:
        """Set ``key`` and notify its subscribers (like NAOqi, inserting a value also raises the event); an event this
        robot does not have (``body.silent_events``, from a recorded profile) is dropped."""
        if self._body is not None and key in self._body.silent_events:
            return
        with self._lock:
            self._data[key] = value
            subscribers = list(self._subscribers.get(key, ()))
        for sub in subscribers:
            sub.signal(value)

    @qi.nobind
    def forget_subscribers(self) -> None:
        """Drop every subscriber (the stand-in stops)."""
        with self._lock:
            self._subscribers.clear()


#: The events the stand-in raises (``Control``: touches, the chest button, falls, heat, the battery, life).
EVENTS = (*BUTTON_LETTERS, "ChestButtonPressed", "ALChestButton/SimpleClickOccurred",
          "ALChestButton/DoubleClickOccurred", "ALChestButton/TripleClickOccurred", "ALMotion/RobotIsFalling",
          "robotHasFallen", "HotDeviceDetected", "BatteryChargeChanged", "ALBattery/BatteryLow", "AutonomousLife/State",
          "ALDiagnosis/RobotIsReady")  # the last: declared, raised by a NAO after its start-up diagnosis only


def _temperature_joint(key: str) -> str | None:
    """The joint of a ``Device/SubDeviceList/<joint>/Temperature/Sensor/Value`` key, else None."""
    head, tail = "Device/SubDeviceList/", "/Temperature/Sensor/Value"
    if key.startswith(head) and key.endswith(tail) and "/" not in key[len(head):-len(tail)]:
        return key[len(head):-len(tail)] or None
    return None


def button_key(button: str) -> str:
    """The ALMemory key of a head button given as a letter (A/B/C), a key or a short name (front/middle/rear)."""
    text = button.strip()
    if text.upper() in _LETTER_BUTTONS:
        return _LETTER_BUTTONS[text.upper()]
    for key in BUTTON_LETTERS:
        if text.lower() in (key.lower(), key.lower().removesuffix("tactiltouched")):
            return key
    raise ValueError(
        f"unknown head button {button!r}: use a letter ({', '.join(_LETTER_BUTTONS)}), "
        f"a key ({', '.join(BUTTON_LETTERS)}) or front/middle/rear"
    )
