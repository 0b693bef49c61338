"""The seam for robot models: what a robot plug-in declares over the one NAOqi adapter.

A model is registered once by name (kind ``robot_model``: ``registry.BUILTIN``, or a package's
``nao_trainer.robot_models`` entry point) at a subclass of :class:`RobotModel`. It owns its settings (a
``core.settings`` dataclass, the ``robot.model_settings`` section of a study config) and declares:

* its postures (what ``ALRobotPosture.goToPosture`` accepts on it) and the safe ones;
* its answer inputs: the ALMemory keys of its head buttons, mapped to the task's letters;
* the ALMemory events of its health (falls, heat, battery, chest button) the session watches;
* the NAOqi services it needs (a missing one fails ``check``) and those it can do without (probed with
  ``has_service``; a missing one degrades with one line saying what is lost);
* what it can do (``capabilities``): e.g. ``sit`` (a seated posture to cool the legs), ``fall``.

The NAOqi adapter (``robot.naoqi.NaoqiRobot``) and the session take all of that from the model; no model
name is compared outside the registry. Light: no qi import here (the config loader builds the settings).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar

from nao_trainer import registry
from nao_trainer.core.settings import build
from nao_trainer.errors import ConfigError


@dataclass(frozen=True)
class Service:
    """A NAOqi service the model uses: ``required`` ones fail ``check``; without an optional one,
    ``without`` says what the session does instead (one line for the operator)."""

    name: str
    required: bool = True
    without: str = ""


@dataclass(frozen=True)
class HealthKeys:
    """The ALMemory events a session watches on this model (empty: not watched). Each names its page."""

    falling: str = ""  # the fall manager started (``ALMotion/RobotIsFalling``)
    fallen: str = ""  # the fall manager finished: the robot is down (``robotHasFallen``)
    hot: str = ""  # a device is hot (``HotDeviceDetected``)
    battery_low: str = ""  # ``ALBattery/BatteryLow`` (deprecated; removed in NAOqi 2.8.6)
    battery_charge: str = ""  # ``BatteryChargeChanged`` (percent): at or below ``battery_low_percent`` it is battery low
    chest: str = ""  # one click of the chest button (``ALChestButton/SimpleClickOccurred``)
    chest_double: str = ""  # a double click of the chest button (``ALChestButton/DoubleClickOccurred``)
    diagnosis: str = ""  # the diagnosis: False = a failure (``ALDiagnosis/RobotIsReady``: documented for the start-up one)
    safeguard: str = ""  # Autonomous Life's state changed (``AutonomousLife/State``): "safeguard" pauses

    def items(self) -> list[tuple[str, str]]:
        """(what, ALMemory key) for each watched event."""
        return [(what, key) for what, key in vars(self).items() if key]


@dataclass(frozen=True)
class Probe:
    """What ``RobotModel.probe`` found: services missing that the task needs, and lines for those it can lose."""

    missing: tuple[str, ...]
    degraded: tuple[str, ...]
    present: frozenset[str]


class RobotModel:
    """Base of robot model plug-ins; a subclass sets the class attributes and ``Settings``."""

    Settings: ClassVar[type]
    #: Shown to operators ("NAO", "Pepper").
    title: ClassVar[str] = "robot"
    postures: ClassVar[tuple[str, ...]] = ()
    safe_postures: ClassVar[tuple[str, ...]] = ()
    #: ALMemory key of each answer button -> the task's letter (A, B, C).
    buttons: ClassVar[dict[str, str]] = {}
    health: ClassVar[HealthKeys] = HealthKeys()
    services: ClassVar[tuple[Service, ...]] = ()
    capabilities: ClassVar[frozenset[str]] = frozenset()
    #: Joints whose temperature ``check`` reads (``Device/SubDeviceList/<joint>/Temperature/Sensor/...``).
    joints: ClassVar[tuple[str, ...]] = ()
    #: What ``ALMotion.getRobotConfig`` / ``ALSystem`` call this model, to tell a wrong ``robot.model``.
    type_names: ClassVar[tuple[str, ...]] = ()

    def __init__(self, name: str, settings: Any) -> None:
        self.name = name
        self.settings = settings

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    def can(self, capability: str) -> bool:
        return capability in self.capabilities

    def cool_posture(self) -> str | None:
        """The posture that rests hot legs between turns (None: the model has none, it pauses instead)."""
        return getattr(self.settings, "cool_posture", None)

    def full_battery_minutes(self) -> float:
        """How long a full charge lasts in a session (``check``'s estimate)."""
        return float(getattr(self.settings, "full_battery_minutes", 60.0))

    def battery_low_percent(self) -> int:
        """The charge (percent) at or below which a ``BatteryChargeChanged`` value counts as battery low (a guess to
        confirm on a robot; a model without the setting gets 15)."""
        return int(getattr(self.settings, "battery_low_percent", 15))

    def heat_c_per_min(self) -> float:
        """How fast (°C a minute) a joint that carries the robot warms while it stands stiff: ``check``'s heat
        projection (a guess to confirm on a robot; a model without the setting gets 1.0)."""
        return float(getattr(self.settings, "heat_c_per_min", 1.0))

    def hot_joint_c(self) -> float:
        """The joint temperature (°C) around which its status turns hot (1) and the stiffness is limited:
        ``check``'s heat projection (a guess to confirm on a robot; a model without the setting gets 70)."""
        return float(getattr(self.settings, "hot_joint_c", 70.0))

    def check_posture(self, which: str, posture: str) -> str | None:
        """A problem with using ``posture`` as the behaviors file's ``which`` posture on this model, or None."""
        allowed = self.safe_postures if which == "safe" else self.postures
        if posture not in allowed:
            return (f"postures.{which} {posture!r} is not a posture of {self.title} "
                    f"(robot.model {self.name!r}); use one of {', '.join(allowed)}")
        return None

    def probe(self, has_service: Callable[[str], bool], needs_buttons: bool = True) -> Probe:
        """Which services the robot offers (``has_service``), once each: missing required ones, degraded lines."""
        present = {s.name for s in self.services if has_service(s.name)}
        if needs_buttons and not self.buttons:
            raise ValueError(f"{self.title} has no answer buttons: answer with the keyboard")
        missing = tuple(s.name for s in self.services if s.required and s.name not in present)
        degraded = tuple(f"{self.title} offers no {s.name}: {s.without}" for s in self.services
                         if not s.required and s.name not in present)
        return Probe(missing, degraded, frozenset(present))


def make_model(name: str, data: Any = None, prefix: str = "robot.model_settings") -> RobotModel:
    """The robot model plug-in ``name`` with its settings built from ``data`` (``SettingError`` naming the dotted
    key under ``prefix``; one ``ConfigError`` line for an unknown or unloadable model)."""
    cls = registry.load("robot_model", name)
    return cls(name, build(cls.Settings, data if data is not None else {}, prefix))


def model_called(type_name: str) -> str | None:
    """The registered robot model whose ``type_names`` hold what the robot calls itself (ALMemory's
    ``RobotConfig/Body/Type``: ``nao``; ``juliette``, Pepper's internal name), else None."""
    for name in registry.names("robot_model"):
        try:
            cls = registry.load("robot_model", name)
        except ConfigError:
            continue  # a plug-in that cannot load here claims no robot
        if type_name in getattr(cls, "type_names", ()):
            return name
    return None


def default_model() -> RobotModel:
    """The default robot model (``robot.model``'s default, the NAO) with its default settings (a robot built
    without a study: tools, tests)."""
    return make_model(registry.default("robot_model"))
