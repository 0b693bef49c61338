"""Find an EEG stream over Lab Streaming Layer (a Muse as muselsl publishes it, a BrainFlow board
republished by its device) and read it.

``resolve_eeg`` looks for streams of a type (default ``EEG``), optionally a name or source_id, and
prefers a stream of the device's name (``Montage.prefer_name``). ``EEGInlet`` reads the channel labels
from the stream description (``channels/channel/label``), keeps the device montage's scalp channels
(for a Muse TP9, AF7, AF8, TP10, dropping ``Right AUX``), and returns samples stamped on this machine's
LSL clock: it applies the inlet's time correction and also maps streams stamped with wall-clock time
(muselsl without ``--lsltime``).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from nao_trainer import registry
from nao_trainer.core.montage import Montage
from nao_trainer.eeg.device import make_device
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.errors import EEGUnavailable

log = logging.getLogger(__name__)

#: Stamps further than this from the local clock are not on the LSL clock (seconds).
CLOCK_MISMATCH_S = 5.0


@dataclass(frozen=True)
class StreamQuery:
    """Which stream to use: a type, and optionally an exact name and/or source_id."""

    stream_type: str = "EEG"
    name: str | None = None
    source_id: str | None = None
    prefer_name: str = "Muse"

    def predicate(self) -> str:
        """An XPath predicate for ``pylsl.resolve_bypred``."""
        parts = [f"type='{_quote(self.stream_type)}'"]
        if self.name:
            parts.append(f"name='{_quote(self.name)}'")
        if self.source_id:
            parts.append(f"source_id='{_quote(self.source_id)}'")
        return " and ".join(parts)

    def pick(self, infos):
        """The stream to use among matching ``pylsl.StreamInfo``s: the first named ``prefer_name``, else the
        first one; None when there is none."""
        infos = list(infos)
        preferred = [i for i in infos if self.prefer_name and i.name() == self.prefer_name]
        return (preferred or infos or [None])[0]

    def describe(self) -> str:
        bits = [f"type {self.stream_type!r}"]
        if self.name:
            bits.append(f"name {self.name!r}")
        if self.source_id:
            bits.append(f"source_id {self.source_id!r}")
        return ", ".join(bits)


def _quote(value: str) -> str:
    if "'" in value:
        raise ValueError(f"LSL stream properties cannot contain a quote: {value!r}")
    return value


def resolve_eeg(query: StreamQuery, timeout_s: float, scope: str = "machine"):
    """The best matching ``pylsl.StreamInfo`` within ``timeout_s``, or None.

    Returns as soon as one match is found. Several matches: a stream named ``prefer_name`` wins,
    then the first found (logged, so the operator sees which one was taken).
    """
    configure_lsl(scope)
    import pylsl

    # A continuous resolver, polled: liblsl's one-shot resolve can overrun a short timeout by ~5 s
    # when nothing matches (seen with pylsl 1.18.6), which would stall a session start.
    resolver = pylsl.ContinuousResolver(pred=query.predicate(), forget_after=5.0)
    deadline = time.monotonic() + float(timeout_s)
    infos = resolver.results()
    while not infos and time.monotonic() < deadline:
        time.sleep(0.02)
        infos = resolver.results()
    if not infos:
        return None
    # Let other matching streams answer too (up to 0.5 s more), so the preferred name can win.
    settle = time.monotonic() + 0.5
    while not any(i.name() == query.prefer_name for i in infos) and time.monotonic() < settle:
        time.sleep(0.05)
        infos = resolver.results() or infos
    chosen = query.pick(infos)
    if len(infos) > 1:
        log.warning("%d EEG streams match %s; using %r (source_id %r)", len(infos), query.describe(),
                    chosen.name(), chosen.source_id())
    return chosen


#: ``desc/acquisition`` values of made-up streams (simulate-muse, the replayer, BrainFlow's synthetic board): not a headband.
SIMULATED_ACQUISITIONS = ("simulated", "replayed", "synthetic")


def acquisition(info) -> str:
    """What the stream says it is in ``desc/acquisition`` ("simulated", "replayed"; "" when unmarked,
    as a headband's bridge such as muselsl leaves it)."""
    return info.desc().child_value("acquisition").strip()


def resolve_all(query: StreamQuery, timeout_s: float, scope: str = "machine", settle_s: float = 1.0) -> list:
    """Every ``pylsl.StreamInfo`` matching ``query``: waits up to ``timeout_s`` for the first, then
    ``settle_s`` more for others to answer (``nao-trainer check`` refuses an ambiguous choice)."""
    configure_lsl(scope)
    import pylsl

    resolver = pylsl.ContinuousResolver(pred=query.predicate(), forget_after=5.0)
    deadline = time.monotonic() + float(timeout_s)
    infos = resolver.results()
    while not infos and time.monotonic() < deadline:
        time.sleep(0.02)
        infos = resolver.results()
    if infos:
        time.sleep(settle_s)
        infos = resolver.results() or infos
    return list(infos)


def channel_labels(info) -> list[str]:
    """Channel labels from ``desc/channels/channel/label`` (empty strings where missing)."""
    labels = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty() and len(labels) < info.channel_count():
        labels.append(ch.child_value("label").strip())
        ch = ch.next_sibling()
    return labels


@dataclass
class EEGInlet:
    """An open LSL inlet on one EEG stream, reading scalp channels stamped on the local LSL clock."""

    inlet: object
    name: str
    source_id: str
    hostname: str
    fs: float
    n_channels: int
    labels: tuple[str, ...]  # all channel labels of the stream
    scalp_index: tuple[int, ...]
    scalp_labels: tuple[str, ...]
    warnings: list[str] = field(default_factory=list)
    offset: float = 0.0  # add to a stream stamp to get local LSL time
    wall_clock: bool | None = None  # None until the first samples tell
    stream_type: str = "EEG"
    acquisition: str = ""  # desc/acquisition: "simulated" / "replayed" for nao-trainer's own streams
    _max_samples: int = 1024

    @classmethod
    def open(cls, info, scope: str = "machine", correction_timeout_s: float = 2.0,
             montage: Montage | None = None) -> "EEGInlet":
        """Open an inlet on ``info`` (from :func:`resolve_eeg`); ``recover=True`` reconnects by itself.

        ``montage``: the device's (``eeg.device.EEGDevice.montage``), naming the scalp channels kept; the default
        device's (``eeg.device``'s default, the Muse) when not given."""
        configure_lsl(scope)
        import pylsl

        if montage is None:
            montage = make_device(registry.default("eeg_device")).montage()
        inlet = pylsl.StreamInlet(info, max_buflen=60, recover=True)
        full = inlet.info(correction_timeout_s)
        labels = channel_labels(full)
        idx, scalp, warning = montage.scalp_index(labels, full.channel_count())
        fs = full.nominal_srate()
        if fs <= 0:
            raise EEGUnavailable(f"LSL stream {full.name()!r} (source_id {full.source_id()!r}) has an irregular "
                                 "rate; an EEG stream needs a nominal sampling rate")
        obj = cls(inlet=inlet, name=full.name(), source_id=full.source_id(), hostname=full.hostname(), fs=fs,
                  n_channels=full.channel_count(), labels=tuple(labels), scalp_index=idx, scalp_labels=scalp,
                  stream_type=full.type(), acquisition=acquisition(full))
        if warning:
            obj.warnings.append(warning)
            log.warning("%s", warning)
        obj.refresh_offset(correction_timeout_s)
        return obj

    def refresh_offset(self, timeout_s: float = 2.0) -> None:
        """Ask liblsl for the clock offset to the stream's host (blocks ~0.6 s the first time)."""
        try:
            self.offset = float(self.inlet.time_correction(timeout_s))
        except Exception as exc:  # pylsl's TimeoutError/LostError are not builtins
            log.warning("LSL time correction for %r failed (%s); keeping offset %.4f s", self.name, exc, self.offset)

    def pull(self, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Scalp samples ``(n, n_scalp)`` float64 and local LSL stamps ``(n,)``; empty when none came.

        Waits up to ``timeout_s`` for the first sample, then returns what is available.
        """
        x, ts = self.inlet.pull_chunk(timeout=timeout_s, max_samples=self._max_samples, min_samples=1,
                                      as_numpy=True)
        if x is None or len(ts) == 0:
            return np.empty((0, len(self.scalp_index))), np.empty(0)
        ts = np.asarray(ts, dtype=float) + self.offset
        self._check_clock(float(ts[-1]))
        if self.wall_clock:
            ts = ts - self._wall_shift()
        return np.asarray(x, dtype=float)[:, self.scalp_index], ts

    @staticmethod
    def _wall_shift() -> float:
        import pylsl

        return time.time() - pylsl.local_clock()

    def _check_clock(self, last_stamp: float) -> None:
        """Detect (again after a reconnection) whether the source stamps with wall-clock time."""
        import pylsl

        now = pylsl.local_clock()
        on_lsl = abs(last_stamp - now) < CLOCK_MISMATCH_S
        on_wall = abs(last_stamp - time.time()) < CLOCK_MISMATCH_S
        if on_lsl and self.wall_clock is not False:
            self.wall_clock = False
        elif on_wall and not on_lsl and self.wall_clock is not True:
            self.wall_clock = True
            msg = (f"stream {self.name!r} is stamped with wall-clock time (muselsl without --lsltime?); "
                   "mapping its stamps to the LSL clock")
            self.warnings.append(msg)
            log.warning("%s", msg)

    @property
    def simulated(self) -> bool:
        """True for a stream nao-trainer made (simulated or replayed), not a headband."""
        return self.acquisition in SIMULATED_ACQUISITIONS

    def identity(self) -> dict:
        """Which stream this is (session.json's ``eeg_stream``): enough to tell two headbands apart."""
        return {"name": self.name, "type": self.stream_type, "source_id": self.source_id, "hostname": self.hostname,
                "channel_count": self.n_channels, "nominal_srate": self.fs,
                "acquisition": self.acquisition or "device", "simulated": self.simulated}

    def describe(self) -> dict:
        """JSON-ready facts about the stream, for the session folder."""
        return {**self.identity(), "name": self.name, "source_id": self.source_id, "hostname": self.hostname,
                "nominal_srate": self.fs, "channel_count": self.n_channels, "labels": list(self.labels),
                "scalp_channels": list(self.scalp_labels), "time_offset_s": self.offset,
                "wall_clock_stamps": self.wall_clock, "warnings": list(self.warnings)}

    def close(self) -> None:
        """Drop the inlet (liblsl disconnects when the last reference goes)."""
        inlet, self.inlet = self.inlet, None
        if inlet is not None:
            try:
                inlet.close_stream()
            except Exception:  # already gone: nothing to release
                pass
