"""The Muse headband over LSL, as muselsl publishes it (``muselsl stream --lsltime``), or simulated.

Registered as EEG device ``muse`` (``registry.BUILTIN``). Its montage: the four scalp channels TP9, AF7,
AF8, TP10 at 256 Hz (``Right AUX`` dropped), the quality thresholds below, and a preference for streams
named ``Muse``. In simulated mode it starts a :class:`~nao_trainer.eeg.simulated_muse.SimulatedMuse` in
this process whose engagement follows the session (``set_target``), pinned by a unique source_id.
"""
from __future__ import annotations

import itertools
import os

import numpy as np

from nao_trainer.core.engagement import QualityThresholds
from nao_trainer.core.eeg import CHANNELS
from nao_trainer.core.montage import Montage
from nao_trainer.core.settings import setting, settings
from nao_trainer.eeg.device import EEGDevice, Source
from nao_trainer.eeg.inlet import StreamQuery  # pylsl-free (pylsl loads when a stream is opened)
from nao_trainer.eeg.simulated_muse import SimulatedMuse, fake_mac

_SIM_COUNTER = itertools.count(1)
MUSE_RATE_HZ = 256.0  # muselsl's nominal rate for the Muse 2016 / 2 / S EEG stream


def _name(value: str) -> str | None:
    return "must not contain a quote (')" if "'" in value else None


@settings
class MuseSettings:
    """``eeg.device_settings`` of the Muse: the preferred stream name and when a channel is not clean EEG
    (``core.engagement.QualityThresholds``; the defaults suit a Muse's dry electrodes)."""

    prefer_name: str = setting("Muse", kind=str, check=_name,
                               doc="among several matching LSL streams, the one of this name wins")
    min_std_uv: float = setting(1.0, kind=(int, float), min=0.0, max=1000.0,
                                doc="below: flat (electrode off the skin), uV")
    max_std_uv: float = setting(100.0, kind=(int, float), above=0.0, max=100000.0,
                                doc="above: implausible amplitude (movement), uV")
    max_ptp_uv: float = setting(600.0, kind=(int, float), above=0.0, max=100000.0,
                                doc="peak-to-peak above: implausible amplitude, uV")
    max_constant_s: float = setting(0.1, kind=(int, float), above=0.0, max=10.0,
                                    doc="one value held this long: saturated, s")

    def __post_init__(self) -> None:
        QualityThresholds(self.min_std_uv, self.max_std_uv, self.max_ptp_uv, self.max_constant_s)  # relations


class MuseDevice(EEGDevice):
    """A Muse via muselsl (live) or the simulated Muse (simulated mode)."""

    Settings = MuseSettings
    start_hint = "start the headband bridge (`muselsl stream --lsltime`) or `nao-trainer simulate-muse`"

    def montage(self, simulated: bool = False) -> Montage:
        s = self.settings
        return Montage(self.name, CHANNELS, MUSE_RATE_HZ,
                       QualityThresholds(s.min_std_uv, s.max_std_uv, s.max_ptp_uv, s.max_constant_s),
                       prefer_name=s.prefer_name, board="simulated Muse" if simulated else "Muse via LSL (muselsl)")

    def open(self, eeg, rng, *, simulated: bool, rest_target: float = 0.5) -> Source:
        montage = self.montage(simulated)
        if not simulated:
            return Source(StreamQuery(eeg.stream_type, eeg.stream_name, eeg.source_id, montage.prefer_name), montage)
        # The simulator draws from its own generator (seeded from the session's) in its own thread,
        # so the session's random stream stays reproducible.
        sim_rng = np.random.default_rng(int(rng.integers(0, 2**63 - 1)))
        # pid + a counter keep source_ids unique across parallel processes and monitors (no cross-talk)
        source_id = f"Muse{fake_mac(sim_rng)}-sim{os.getpid()}-{next(_SIM_COUNTER)}"
        sim = SimulatedMuse.start(sim_rng, target=rest_target, source_id=source_id, scope=eeg.lsl_scope)
        return Source(StreamQuery("EEG", None, source_id, montage.prefer_name), montage, sim)
