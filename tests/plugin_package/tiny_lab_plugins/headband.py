"""The EEG device ``tinyband``: a four-channel headband with its own settings and montage; simulated by
nao-trainer's simulated Muse (the same four scalp channels), under its own name and source_id."""
from __future__ import annotations

import itertools
import os

import numpy as np

from nao_trainer.core.engagement import QualityThresholds
from nao_trainer.core.eeg import CHANNELS
from nao_trainer.core.montage import Montage
from nao_trainer.core.settings import setting, settings
from nao_trainer.eeg.device import EEGDevice, Source
from nao_trainer.eeg.inlet import StreamQuery
from nao_trainer.eeg.simulated_muse import SimulatedMuse

_COUNTER = itertools.count(1)


@settings
class TinyBandSettings:
    max_std_uv: float = setting(150.0, kind=(int, float), above=0.0, max=1000.0,
                                doc="above: implausible amplitude, uV")


class TinyBand(EEGDevice):
    """A lab's four-channel headband (a test plug-in)."""

    Settings = TinyBandSettings
    start_hint = "start the tinyband bridge"

    def montage(self, simulated: bool = False) -> Montage:
        return Montage(self.name, CHANNELS, 256.0, QualityThresholds(1.0, self.settings.max_std_uv, 600.0, 0.1),
                       prefer_name="TinyBand", board="simulated tinyband" if simulated else "tinyband")

    def open(self, eeg, rng, *, simulated: bool, rest_target: float = 0.5) -> Source:
        montage = self.montage(simulated)
        if not simulated:
            return Source(StreamQuery(eeg.stream_type, eeg.stream_name, eeg.source_id, montage.prefer_name), montage)
        source_id = f"tinyband-sim{os.getpid()}-{next(_COUNTER)}"
        sim = SimulatedMuse.start(np.random.default_rng(int(rng.integers(0, 2**63 - 1))), target=rest_target, name="TinyBand",
                                  source_id=source_id, scope=eeg.lsl_scope)
        return Source(StreamQuery("EEG", None, source_id, montage.prefer_name), montage, sim)
