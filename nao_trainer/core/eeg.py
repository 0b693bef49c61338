"""EEG facts and processing settings shared by the live monitor (``eeg/``) and the offline pipeline (``data/``).

Defined here, in the lowest layer that needs them, so that neither side imports the other: the
channel order and raw rate of a Muse (and of the published recordings), and the engagement
processing options of ``eeg.processing`` in a study config. Pure: no I/O.
"""
from __future__ import annotations

from typing import Any, Mapping

from nao_trainer.core.settings import SettingError, build, setting, settings

#: Scalp channel order of every 4-value line (and of a Muse's LSL stream, before ``Right AUX``).
CHANNELS: tuple[str, ...] = ("TP9", "AF7", "AF8", "TP10")
#: Nominal rate of the raw ``eeg`` lines (Muse 2016 via the Muse SDK; dataset README), Hz.
RAW_RATE_HZ = 220.0


@settings
class Processing:
    """Engagement processing options (``eeg.processing`` in a study config).

    window_s / hop_s: analysis window and step (2 s windows every 0.25 s: 1 Hz Welch resolution,
    four values a second). ewma_a: smoothing factor a of ``s_t = a s_(t-1) + (1-a) y_t``; 0.75 at
    4 windows/s gives a time constant hop/(1-a) = 1 s, the authors' 0.9 at their 10 Hz band rate.
    resolve_timeout_s: how long to look for the stream at start. loss_timeout_s: silence after
    which the stream counts as lost. min_quality: clean fraction a phase needs for a value.
    min_clean_channels: clean scalp channels a window needs. gap_tolerance_s: a jump in sample
    stamps larger than this restarts the windows. end_wait_s: longest wait at a phase end for
    samples still in flight. poll_s: how often the reader drains the inlet between phase ends (a
    phase end drains it at once; 0.2 s keeps the reader well under 1 % of a core). record_raw: save the scalp samples to ``eeg/raw.csv``.
    """

    window_s: float = setting(2.0, kind=(int, float), min=0.25, max=30.0, doc="analysis window, s")
    hop_s: float = setting(0.25, kind=(int, float), min=0.01, max=30.0, doc="step between windows, s")
    ewma_a: float = setting(0.75, kind=(int, float), min=0.0, max=0.999, doc="smoothing factor a")
    resolve_timeout_s: float = setting(5.0, kind=(int, float), min=0.0, max=120.0, doc="look for the stream, s")
    loss_timeout_s: float = setting(1.0, kind=(int, float), min=0.1, max=60.0, doc="silence = lost, s")
    min_quality: float = setting(0.5, kind=(int, float), min=0.0, max=1.0, doc="clean fraction a phase needs")
    min_clean_channels: int = setting(2, kind=int, min=1, max=4, doc="clean scalp channels a window needs")
    gap_tolerance_s: float = setting(0.1, kind=(int, float), min=0.0, max=10.0, doc="stamp jump that restarts, s")
    end_wait_s: float = setting(0.04, kind=(int, float), min=0.0, max=1.0, doc="wait at a phase end, s")
    poll_s: float = setting(0.2, kind=(int, float), min=0.005, max=1.0, doc="reader poll interval, s")
    record_raw: bool = setting(True, kind=bool, doc="save the scalp samples to eeg/raw.csv")

    def __post_init__(self) -> None:
        if self.hop_s > self.window_s:
            raise SettingError("hop_s", f"must not exceed window_s ({self.window_s:g}), got {self.hop_s!r}; "
                                        "use a hop no longer than the window")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None, prefix: str = "eeg.processing") -> "Processing":
        """Validate ``eeg.processing`` (``core.settings.build``); ``SettingError`` naming the key."""
        return build(cls, dict(data or {}), prefix)
