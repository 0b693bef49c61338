"""EEG facts and processing settings shared by the live monitor (``eeg/``) and the offline pipeline (``data/``).

Defined here, in the lowest layer that needs them, so that neither side imports the other: the
channel order and raw rate of a Muse (and of the published recordings), and the engagement
processing options of ``eeg.processing`` in a study config. Pure: no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

from nao_trainer.errors import ConfigError

#: Scalp channel order of every 4-value line (and of a Muse's LSL stream, before ``Right AUX``).
CHANNELS: tuple[str, ...] = ("TP9", "AF7", "AF8", "TP10")
#: Nominal rate of the raw ``eeg`` lines (Muse 2016 via the Muse SDK; dataset README), Hz.
RAW_RATE_HZ = 220.0


@dataclass(frozen=True)
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

    window_s: float = 2.0
    hop_s: float = 0.25
    ewma_a: float = 0.75
    resolve_timeout_s: float = 5.0
    loss_timeout_s: float = 1.0
    min_quality: float = 0.5
    min_clean_channels: int = 2
    gap_tolerance_s: float = 0.1
    end_wait_s: float = 0.04
    poll_s: float = 0.2
    record_raw: bool = True

    def __post_init__(self) -> None:
        rules = {
            "window_s": (0.25, 30.0), "hop_s": (0.01, 30.0), "ewma_a": (0.0, 0.999),
            "resolve_timeout_s": (0.0, 120.0), "loss_timeout_s": (0.1, 60.0), "min_quality": (0.0, 1.0),
            "min_clean_channels": (1, 4), "gap_tolerance_s": (0.0, 10.0), "end_wait_s": (0.0, 1.0), "poll_s": (0.005, 1.0),
        }
        for key, (lo, hi) in rules.items():
            value = getattr(self, key)
            if not lo <= value <= hi:
                raise ConfigError(f"eeg.processing.{key}: {value!r} is out of range; use a value in [{lo}, {hi}]")
        if self.hop_s > self.window_s:
            raise ConfigError(f"eeg.processing.hop_s: {self.hop_s} exceeds window_s {self.window_s}; "
                              "use a hop no longer than the window")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None) -> "Processing":
        """Validate ``eeg.processing``; unknown keys and wrong types raise ``ConfigError`` naming the key."""
        data = dict(data or {})
        known = {f.name: f for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            if key not in known:
                raise ConfigError(f"eeg.processing.{key}: unknown key; known keys are {', '.join(known)}")
            default = known[key].default
            if isinstance(default, bool):
                if not isinstance(value, bool):
                    raise ConfigError(f"eeg.processing.{key}: must be true or false, got {value!r}")
            elif isinstance(default, int):
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ConfigError(f"eeg.processing.{key}: must be an integer, got {value!r}")
            elif isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"eeg.processing.{key}: must be a number, got {value!r}")
            values[key] = float(value) if isinstance(default, float) else value
        return cls(**values)
