"""A NAO stand-in served over a real ``qi`` session, for development, CI and offline studies.

The stand-in offers the NAOqi services the project uses, under NAOqi's names and signatures, so
the client (``nao_trainer.robot.naoqi.NaoqiRobot``) talks to it exactly as it talks to a NAO:

* ``ALTextToSpeech``  say(text) / say(text, language), setLanguage, getLanguage, setParameter,
  getParameter, setVolume, getVolume, stopAll (cuts the speech in progress short)
* ``ALAnimatedSpeech`` say(text) / say(text, configuration)
* ``ALAudioPlayer``   playSine(frequency, gain, pan, duration), stopAll
* ``ALLeds``          fadeRGB(name, rgb, secs) / fadeRGB(name, r, g, b, secs), reset, on, off
* ``ALRobotPosture``  goToPosture(name, speed) -> bool, getPosture, getPostureList
* ``ALMotion``        wakeUp, rest, robotIsWakeUp
* ``ALMemory``        subscriber(key) (object with ``.signal``), raiseEvent, insertData, getData
* ``ALAutonomousLife`` getState, setState (boots "solitary"); ``ALAudioDevice`` getOutputVolume,
  setOutputVolume, isAudioOutMuted, muteAudioOut; ``ALBattery`` getBatteryCharge; ``ALSystem``
  robotName, systemVersion (``body``)
* ``NaoTrainerStandIn`` (control, not NAOqi) press(button or letter), hold, hold_after, chest(clicks),
  chest_after, bounce, body, set_battery, set_latency, freeze, freeze_after, transcript(), clear(),
  set_speed(x), speed(); the robot's health: fall, stand_up, heat(joint, status), warm(joint, celsius), battery_low, safeguard,
  refuse_life(bool), set_languages(list), set_chest_double("stiffness" or "life"), act_after(call, action, args) (``body`` cites the pages)
* ``StandIn.start(model="pepper", without=(...), profile=...)``: plays a Pepper, lacks services, or answers as a
  recorded robot did (``robot.profile``)

Clients reach the qi server through a ``link.Link`` (latency, a frozen link, the tcps login).

Speech and motion take time (``SECONDS_PER_CHARACTER`` per character, a beep its duration,
divided by the speed factor) so sessions keep realistic timing that tests can speed up. Every
call is recorded in a transcript: in memory and, when a path is given, appended to a JSON-lines
file flushed per line: ``{"t": s_since_start, "service": ..., "method": ..., "args": [...]}``.

Modules: ``recorder`` (speed factor and transcript), ``services`` (the NAOqi services),
``server`` (:class:`StandIn`, ``serve``, ``spawn_standin``), ``client`` (:class:`StandInClient`).
"""
from __future__ import annotations

from nao_trainer.robot.standin.body import LIFE_STATES, SLEEP_HOLD_S, Body
from nao_trainer.robot.standin.client import StandInClient
from nao_trainer.robot.standin.login import Login
from nao_trainer.robot.standin.recorder import Recorder
from nao_trainer.robot.standin.server import READY_PREFIX, StandIn, check_listen_url, serve, spawn_standin
from nao_trainer.robot.standin.services import (BODY_LANGUAGE_MODES, POSTURE_SECONDS, POSTURES, PRESS_HOLD_S,
                                                SECONDS_PER_CHARACTER, button_key)

__all__ = ["LIFE_STATES", "SLEEP_HOLD_S", "Body", "Login", "BODY_LANGUAGE_MODES", "POSTURES", "POSTURE_SECONDS", "PRESS_HOLD_S", "READY_PREFIX",
           "SECONDS_PER_CHARACTER", "Recorder", "StandIn", "StandInClient", "button_key", "check_listen_url",
           "serve", "spawn_standin"]
