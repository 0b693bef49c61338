"""The seam for EEG devices: what a headband plug-in declares and does.

A device is registered once by name (kind ``eeg_device``: ``registry.BUILTIN``, or a package's
``nao_trainer.eeg_devices`` entry point) at a subclass of :class:`EEGDevice`. It owns its settings (a
``core.settings`` dataclass, the ``eeg.device_settings`` section of a study config), declares its
:class:`~nao_trainer.core.montage.Montage` (channels, rate, quality thresholds, preferred stream name)
and opens its source: a stream that reaches the monitor over LSL, pinned by source_id when the device
makes it in this process (a simulated Muse, a BrainFlow board republished to LSL), so the monitor,
``session.xdf`` and ``check`` read every headband through one path.

Light on purpose: no pylsl or numpy import at module level (the config loader builds device settings).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from nao_trainer import registry
from nao_trainer.core.montage import Montage
from nao_trainer.core.settings import build


@dataclass
class Source:
    """Where the monitor finds a device's samples.

    ``query`` matches the LSL stream (``eeg.inlet.StreamQuery``); ``producer`` is what this process runs to
    make it (``stop()``; ``set_target(x)`` when a simulation follows the session's engagement), or None when
    an outside bridge (muselsl) publishes it."""

    query: Any
    montage: Montage
    producer: Any = None

    def stop(self) -> None:
        if self.producer is not None:
            self.producer.stop()


class EEGDevice:
    """Base of EEG device plug-ins: ``Settings`` (a settings dataclass), ``montage()``, ``open()``."""

    #: The settings dataclass of ``eeg.device_settings`` (declared with ``core.settings``).
    Settings: ClassVar[type]
    #: True when the device makes its stream in this process even for a live headband (BrainFlow):
    #: ``check`` then opens it to report the board, its channels and contact, also in simulated mode.
    opens_in_process: ClassVar[bool] = False
    #: What the operator starts so that the stream exists (in the "no stream" messages).
    start_hint: ClassVar[str] = "start the headband"

    def __init__(self, name: str, settings: Any) -> None:
        self.name = name
        self.settings = settings

    def montage(self, simulated: bool = False) -> Montage:
        """The montage of the live headband or (``simulated``) of the device's simulation."""
        raise NotImplementedError

    def open(self, eeg: Any, rng: Any, *, simulated: bool, rest_target: float = 0.5) -> Source:
        """Start what makes the stream (if anything) and say how to match it. ``eeg`` is the study's
        ``EEGSettings``; ``rng`` a ``numpy.random.Generator`` seeding any simulation."""
        raise NotImplementedError


def make_device(name: str, data: Any = None, prefix: str = "eeg.device_settings") -> EEGDevice:
    """The device plug-in ``name`` with its settings built from ``data`` (``SettingError`` naming the dotted
    key under ``prefix``; one ``ConfigError`` line for an unknown or unloadable device)."""
    cls = registry.load("eeg_device", name)
    return cls(name, build(cls.Settings, data if data is not None else {}, prefix))
