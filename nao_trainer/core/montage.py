"""What an EEG device declares about its signal: a ``Montage``, read alike by the inlet, the monitor,
``nao-trainer check`` and the offline pipeline.

A device plug-in (``eeg/devices/``, registered as kind ``eeg_device`` in ``registry.BUILTIN``) says which
scalp channels it has (their labels, in the order analysed), its nominal rate, when a channel's window is
not clean EEG (``QualityThresholds``) and how its stream is recognised among others (the LSL stream name it
prefers). The live monitor writes the montage into ``eeg/stream.json`` so that the offline re-analysis
(``data/own.py``) applies the very thresholds the session used. Pure: no I/O.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping

from nao_trainer.core.engagement import QualityThresholds


@dataclass(frozen=True)
class Montage:
    """A device's scalp channels, rate, quality thresholds and stream match."""

    device: str  # the registered device name ("muse", "brainflow")
    labels: tuple[str, ...]  # scalp channels analysed, in stream order (others, e.g. Right AUX, are dropped)
    rate_hz: float  # nominal sampling rate (the stream's own nominal rate is what the inlet uses)
    thresholds: QualityThresholds = field(default_factory=QualityThresholds)
    prefer_name: str | None = None  # among several matching streams, one of this name wins
    board: str = ""  # the hardware behind it ("Muse 2 (BrainFlow board 38)"), for check and stream.json

    def __post_init__(self) -> None:
        if not self.labels:
            raise ValueError(f"EEG device {self.device!r}: a montage needs at least one scalp channel")
        if not self.rate_hz > 0:
            raise ValueError(f"EEG device {self.device!r}: a montage needs a rate > 0, got {self.rate_hz!r}")

    def scalp_index(self, stream_labels: list[str], n_channels: int) -> tuple[tuple[int, ...], tuple[str, ...], str]:
        """Indices and names of this montage's channels in a stream, and a warning ("" if none).

        Matched by label (case-insensitive), in stream order; a stream without any of the labels is assumed
        to carry the montage's channels first, in the montage's order, and the warning says so."""
        wanted = {label.upper() for label in self.labels}
        idx = tuple(i for i, label in enumerate(stream_labels) if label.strip().upper() in wanted)
        if idx:
            return idx, tuple(stream_labels[i].strip() for i in idx), ""
        n = min(len(self.labels), n_channels)
        warning = (f"the stream has none of the {self.device} channel labels ({', '.join(stream_labels) or 'none'}); "
                   f"assuming its first {n} channels are {', '.join(self.labels[:n])}")
        return tuple(range(n)), self.labels[:n], warning

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``eeg/stream.json``'s ``montage``)."""
        return {"device": self.device, "labels": list(self.labels), "rate_hz": self.rate_hz,
                "thresholds": asdict(self.thresholds), "prefer_name": self.prefer_name, "board": self.board}


def thresholds_from(data: Mapping[str, Any] | None) -> QualityThresholds:
    """The ``QualityThresholds`` a ``Montage.to_dict()`` recorded; the defaults (a Muse's) where absent,
    as in sessions recorded before devices declared their montage. ``ValueError`` for an invalid record."""
    if not isinstance(data, Mapping):
        return QualityThresholds()
    known = {f.name for f in fields(QualityThresholds)}
    return QualityThresholds(**{k: v for k, v in data.items() if k in known})
