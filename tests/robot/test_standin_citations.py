"""Every behaviour the stand-in shows cites the NAOqi 2.8 page it follows, or says it is a guess to confirm with
the conformance kit (issue 27). Fast: reads the docstrings of the methods each served service exposes over qi."""
from __future__ import annotations

import inspect
import re

from nao_trainer.robot.standin.body import Body
from nao_trainer.robot.standin.control import build_services
from nao_trainer.robot.standin.recorder import Recorder

CITATION = re.compile(r"http://doc\.aldebaran\.com/2-8/[\w/.-]+?\.html")
GUESS = re.compile(r"\bguess\b", re.IGNORECASE)
#: Pages of the NAOqi 2.8 documentation the stand-in may cite (each checked to exist); a new citation is added
#: here only once its page is checked, so a mistyped page fails this test.
PAGES = {
    "naoqi/audio/altexttospeech-api.html", "naoqi/audio/alanimatedspeech-api.html",
    "naoqi/audio/alaudioplayer-api.html", "naoqi/audio/alaudiodevice-api.html", "naoqi/sensors/alleds-api.html",
    "naoqi/motion/alrobotposture-api.html", "naoqi/motion/control-stiffness-api.html",
    "naoqi/motion/reflexes-diagnosis.html", "naoqi/motion/reflexes-fall-manager.html",
    "naoqi/core/almemory-api.html", "naoqi/interaction/autonomouslife-api.html", "naoqi/sensors/albattery-api.html",
    "naoqi/core/alsystem-api.html", "naoqi/sensors/albodytemperature.html", "naoqi/sensors/alchestbutton.html",
    "naoqi/sensors/altouch.html", "family/nao_user_guide/activity_nao.html", "family/nao_user_guide/sleep_nao.html",
    # checked in the NAOqi 2.8.7.4 documentation mirrored in the public repository Cartheur-Nao/aldeb-2.8.7.4:
    "naoqi/sensors/alchestbutton-api.html", "family/nao_user_guide/chest_button_usages.html",
    "family/nao_technical/lola/actuator_sensor_names.html",
    "naoqi/sensors/albattery.html", "news/2.8/whatsnew2.8.6.html",
}
#: The control service's methods that steer the stand-in (timing, links, the transcript) rather than show what a
#: robot does: nothing to cite.
HARNESS = {"set_battery", "set_latency", "freeze", "freeze_after", "freeze_at", "hold_after", "chest_after", "act_after", "body",
           "transcript", "clear", "set_speed", "speed"}


def served_methods(service: object) -> dict[str, str]:
    """name -> docstring of every method qi serves for ``service`` (bound or public; not ``qi.nobind``)."""
    methods = {}
    for name, member in inspect.getmembers(type(service), inspect.isfunction):
        if name.startswith("_") or getattr(member, "__qi_signature__", None) == "DONOTBIND":
            continue
        methods[name] = inspect.getdoc(member) or ""
    return methods


def uncited(services: dict[str, object], harness: dict[str, set[str]]) -> list[str]:
    """``service.method`` of each served method whose docstring neither cites a page nor says "guess"."""
    missing = []
    for service_name, service in sorted(services.items()):
        for name, doc in sorted(served_methods(service).items()):
            if name in harness.get(service_name, set()):
                continue
            if not CITATION.search(doc) and not GUESS.search(doc):
                missing.append(f"{service_name}.{name}")
    return missing


def _services() -> dict[str, object]:
    services, _, _ = build_services(Recorder(speed=1.0), Body())
    return services


def test_every_served_method_of_the_standin_cites_its_page_or_says_it_is_a_guess():
    services = _services()
    assert {"ALTextToSpeech", "ALMotion", "ALMemory", "ALAutonomousLife", "ALBattery", "NaoTrainerStandIn"} <= set(services)
    assert uncited(services, {"NaoTrainerStandIn": HARNESS}) == []
    assert HARNESS <= set(served_methods(services["NaoTrainerStandIn"])), "HARNESS names a method that is gone"


def test_every_cited_page_is_one_checked_to_exist():
    cited = set()
    for service in _services().values():
        for doc in served_methods(service).values():
            cited |= {url.removeprefix("http://doc.aldebaran.com/2-8/") for url in CITATION.findall(doc)}
    assert cited and cited <= PAGES, f"unchecked pages: {sorted(cited - PAGES)}"


def test_a_method_without_a_citation_or_a_guess_is_caught():
    class Uncited:
        def say(self, text: str) -> None:
            """Speaks."""

        def cited(self) -> None:
            """Follows http://doc.aldebaran.com/2-8/naoqi/audio/altexttospeech-api.html."""

        def guessed(self) -> None:
            """A guess to confirm with the conformance kit."""

    assert uncited({"ALFake": Uncited()}, {}) == ["ALFake.say"]
    assert uncited({"ALFake": Uncited()}, {"ALFake": {"say"}}) == []
