"""A simulated Muse headband published over Lab Streaming Layer, and a replayer of recordings.

``SimulatedMuse`` publishes a stream laid out like muselsl's (name ``Muse``, type ``EEG``, 256 Hz
float32, channels TP9 AF7 AF8 TP10 Right AUX in microvolts, source_id ``Muse<MAC>``, chunks of 12)
whose band content follows a target engagement in [0, 1]: the beta / (alpha + theta) power ratio
rises monotonically with the target, so the project's engagement index can be exercised end to end
without a headband. ``ReplayMuse`` plays the raw ``eeg`` lines of a published session (``intro``,
``robot_N``, ``user_N``; ~220 Hz, four channels) back as a live stream, in recording order.

Both push in real time from a background thread, stamped with the LSL clock (muselsl's
``--lsltime``; pass ``wall_clock=True`` to stamp with ``time.time()`` like muselsl's default).
"""
from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nao_trainer.core.eeg import CHANNELS, RAW_RATE_HZ
from nao_trainer.data.own import find_own_sessions, is_own_session, read_raw
from nao_trainer.data.published import read_recording
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.errors import DataError
from nao_trainer.files import read_json

MUSE_LABELS = CHANNELS + ("Right AUX",)
MUSE_RATE_HZ = 256.0
MUSE_CHUNK = 12

#: Engagement ratio beta / (alpha + theta) of the oscillatory power at target 0 and at target 1.
RATIO_LOW, RATIO_HIGH = 0.25, 2.5
OSC_POWER_UV2 = 120.0  # total oscillatory power per scalp channel
#: Component centre frequencies (Hz) and the band each must stay inside while jittering.
COMPONENTS = (
    ("theta", 6.0, (4.5, 7.5)),
    ("alpha", 10.5, (8.5, 12.5)),
    ("beta", 16.0, (13.5, 18.5)),
    ("beta", 21.0, (18.5, 24.0)),
    ("beta", 26.5, (24.0, 29.0)),
)


def target_ratio(target: float) -> float:
    """The beta / (alpha + theta) power ratio the simulated signal shows for ``target`` in [0, 1].

    Log-linear, hence strictly increasing: equal target steps multiply the ratio equally.
    """
    return float(RATIO_LOW * (RATIO_HIGH / RATIO_LOW) ** float(np.clip(target, 0.0, 1.0)))


def _check_target(target: float) -> float:
    value = float(target)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"target engagement must lie in [0, 1], got {target!r}")
    return value


class MuseSignal:
    """Sample generator: DC offset + jittered theta/alpha/beta sinusoids + 1/f-like noise.

    Pure numpy, no I/O; phases and noise state carry over between calls so consecutive chunks
    join seamlessly. ``faults`` maps a channel index to "flat" or "saturated" to imitate a lost
    electrode contact or a railed amplifier.
    """

    def __init__(self, rng: np.random.Generator, fs: float = MUSE_RATE_HZ, target: float = 0.5,
                 n_channels: int = len(MUSE_LABELS)) -> None:
        self.rng = rng
        self.fs = float(fs)
        self.n_channels = n_channels
        self.n_scalp = min(4, n_channels)
        n_comp = len(COMPONENTS)
        self._band = np.array([c[0] for c in COMPONENTS])
        self._lo = np.array([c[2][0] for c in COMPONENTS])
        self._hi = np.array([c[2][1] for c in COMPONENTS])
        centre = np.array([c[1] for c in COMPONENTS])
        self._freq = np.clip(centre + rng.uniform(-0.5, 0.5, (self.n_scalp, n_comp)), self._lo, self._hi)
        self._phase = rng.uniform(0.0, 2 * np.pi, (self.n_scalp, n_comp))
        self._dc = rng.normal(0.0, 15.0, n_channels)
        self._ar = np.zeros(n_channels)  # state of the slow (pink-ish) noise
        self._target = _check_target(target)
        self._weights = self._component_weights(self._target)
        self.faults: dict[int, str] = {}
        self._n = 0  # samples generated so far

    def set_target(self, target: float) -> None:
        self._target = _check_target(target)

    def _component_weights(self, target: float) -> np.ndarray:
        """Power of each component so that beta / (alpha + theta) = ``target_ratio(target)``."""
        r = target_ratio(target)
        slow = OSC_POWER_UV2 / (1.0 + r)
        is_beta = self._band == "beta"
        power = np.where(is_beta, r * slow / is_beta.sum(), slow / (~is_beta).sum())
        return power

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples, shape (n, n_channels), microvolts, float64."""
        rng = self.rng
        # Glide towards the target's power mix (time constant ~0.15 s) instead of jumping.
        goal = self._component_weights(self._target)
        k = 1.0 - np.exp(-n / (0.15 * self.fs))
        self._weights = self._weights + k * (goal - self._weights)
        # Frequencies wander slowly inside their band (jitter), amplitudes wobble by ~10 %.
        self._freq = np.clip(self._freq + rng.normal(0.0, 0.03, self._freq.shape), self._lo, self._hi)
        amp = np.sqrt(2.0 * self._weights) * (1.0 + rng.normal(0.0, 0.1, self._freq.shape))
        steps = np.arange(1, n + 1)[:, None, None] * (2 * np.pi * self._freq / self.fs)[None]
        phases = self._phase[None] + steps  # (n, scalp, comp)
        self._phase = np.mod(phases[-1], 2 * np.pi)
        osc = (amp[None] * np.sin(phases)).sum(axis=2)  # (n, scalp)
        # 1/f-like background: a slow AR(1) random walk plus white noise.
        white = rng.normal(0.0, 1.0, (n, self.n_channels))
        slow_drive = rng.normal(0.0, 1.0, (n, self.n_channels))
        pole = 0.97
        slow = np.empty((n, self.n_channels))
        state = self._ar
        for i in range(n):  # n is a chunk (12): a tiny loop beats building a filter
            state = pole * state + slow_drive[i]
            slow[i] = state
        self._ar = state
        x = self._dc[None] + 2.0 * white + 0.8 * slow
        x[:, : self.n_scalp] += osc
        for ch, kind in self.faults.items():
            if kind == "flat":
                x[:, ch] = self._dc[ch]
            elif kind == "saturated":
                # pinned at the rail of muselsl's +-1000 uV range, with brief returns every 0.5 s
                idx = self._n + np.arange(n)
                x[:, ch] = np.where(idx % int(self.fs / 2) < 4, x[:, ch], 1000.0)
        self._n += n
        return x


@dataclass
class _Publisher:
    """Shared machinery: one outlet, one real-time pushing thread, explicit stop."""

    name: str
    source_id: str
    labels: tuple[str, ...]
    fs: float
    chunk: int
    wall_clock: bool
    scope: str
    samples_pushed: int = 0
    _outlet: object = None
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _paused: threading.Event = field(default_factory=threading.Event)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    error: BaseException | None = None
    #: ``desc/acquisition`` of the stream: what it is, so a session never takes it for a headband
    #: (eeg/inlet.py ``SIMULATED_ACQUISITIONS``); the name stays Muse-like for muselsl-style clients.
    acquisition = "simulated"
    origin = ""  # ``desc/replay_of``: the recording a replay plays

    def _open_outlet(self) -> None:
        configure_lsl(self.scope)
        import pylsl

        info = pylsl.StreamInfo(self.name, "EEG", len(self.labels), self.fs, pylsl.cf_float32, self.source_id)
        desc = info.desc()
        desc.append_child_value("manufacturer", "nao-trainer")  # not InteraXon: a Muse-like stream, made here
        desc.append_child_value("acquisition", self.acquisition)
        desc.append_child_value("generator", f"nao-trainer simulate-muse ({self.acquisition})")
        if self.origin:
            desc.append_child_value("replay_of", self.origin)
        channels = desc.append_child("channels")
        for label in self.labels:
            ch = channels.append_child("channel")
            ch.append_child_value("label", label)
            ch.append_child_value("unit", "microvolts")
            ch.append_child_value("type", "EEG")
        self._outlet = pylsl.StreamOutlet(info, self.chunk, 360)

    def _samples(self, n: int) -> np.ndarray | None:  # overridden
        raise NotImplementedError

    def _run(self) -> None:
        import pylsl

        try:
            t0 = pylsl.local_clock()
            wall_offset = time.time() - t0
            sent = 0
            while not self._stop.is_set():
                if self._paused.is_set():  # a headband gone silent: the outlet stays, no samples
                    self._stop.wait(0.02)
                    t0 = pylsl.local_clock() - sent / self.fs  # on resume, samples continue from now
                    continue
                due = int((pylsl.local_clock() - t0) * self.fs)
                while due - sent >= self.chunk and not self._stop.is_set():
                    with self._lock:
                        x = self._samples(self.chunk)
                    if x is None:  # a replay reached its end
                        self._stop.set()
                        break
                    stamps = t0 + (sent + np.arange(1, len(x) + 1)) / self.fs
                    if self.wall_clock:
                        stamps = stamps + wall_offset
                    self._outlet.push_chunk(np.ascontiguousarray(x, dtype=np.float32), float(stamps[-1]))
                    sent += len(x)
                    self.samples_pushed = sent
                next_due = t0 + (sent + self.chunk) / self.fs
                self._stop.wait(max(0.0, next_due - pylsl.local_clock()))
        except BaseException as exc:  # keep it for the owner; a publisher thread must not die silently
            self.error = exc

    def _start_thread(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"lsl-{self.source_id}", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def has_consumers(self) -> bool:
        """An inlet (a monitor, a recorder) is connected to the stream."""
        outlet = self._outlet
        return bool(outlet is not None and outlet.have_consumers())

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the stream ends (replay finished or ``stop``); True if it ended."""
        if self._thread is not None:
            self._thread.join(timeout)
        return not self.running

    def pause(self) -> None:
        """Stop pushing but keep the outlet (a headband out of range while its bridge runs); ``resume()``."""
        self._paused.set()

    def resume(self) -> None:
        """Push again after ``pause()``; the stamps continue from now (the pause is a gap in the data)."""
        self._paused.clear()

    def stop(self) -> None:
        """Stop pushing and destroy the outlet: inlets see the stream disappear."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._outlet = None  # pylsl destroys the outlet when its last reference goes

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def fake_mac(rng: np.random.Generator) -> str:
    """A Muse-like MAC address ``00:55:DA:xx:xx:xx`` (InteraXon's prefix) drawn from ``rng``."""
    tail = rng.integers(0, 256, 3)
    return "00:55:DA:" + ":".join(f"{b:02X}" for b in tail)


class SimulatedMuse(_Publisher):
    """A live muselsl-compatible EEG stream whose engagement follows ``set_target``."""

    signal: MuseSignal

    @classmethod
    def start(cls, rng: np.random.Generator, target: float = 0.5, *, name: str = "Muse",
              source_id: str | None = None, fs: float = MUSE_RATE_HZ, chunk: int = MUSE_CHUNK,
              wall_clock: bool = False, scope: str = "machine") -> "SimulatedMuse":
        """Open the outlet and start pushing in real time; ``stop()`` closes it."""
        sim = cls(name=name, source_id=source_id or f"Muse{fake_mac(rng)}", labels=MUSE_LABELS,
                  fs=float(fs), chunk=int(chunk), wall_clock=wall_clock, scope=scope)
        sim.signal = MuseSignal(rng, fs=fs, target=target)
        sim._open_outlet()
        sim._start_thread()
        return sim

    def set_target(self, target: float) -> None:
        """Engagement in [0, 1] the signal shows from now on (glides in over ~0.15 s)."""
        with self._lock:
            self.signal.set_target(target)

    def set_fault(self, channel: int, kind: str | None) -> None:
        """Make ``channel`` "flat", "saturated", or healthy again (None)."""
        if kind not in (None, "flat", "saturated"):
            raise ValueError(f"fault must be 'flat', 'saturated' or None, got {kind!r}")
        with self._lock:
            if kind is None:
                self.signal.faults.pop(channel, None)
            else:
                self.signal.faults[channel] = kind

    def _samples(self, n: int) -> np.ndarray:
        return self.signal.next(n)


# ----------------------------------------------------------------------------------------------
# Replay of the published raw recordings
# ----------------------------------------------------------------------------------------------

_TURN_FILE = re.compile(r"^(robot|user)_(\d+)$")


def raw_recording_order(session_dir: Path) -> list[Path]:
    """The raw files of a published session in recording order: intro, robot_1, user_1, robot_2, ..."""
    session_dir = Path(session_dir)
    if not session_dir.is_dir():
        raise DataError(f"{session_dir}: not a folder; give a session folder holding intro, robot_N, user_N")
    turns = []
    for p in session_dir.iterdir():
        m = _TURN_FILE.match(p.name)
        if m and p.is_file():
            turns.append((int(m.group(2)), 0 if m.group(1) == "robot" else 1, p))
    files = ([session_dir / "intro"] if (session_dir / "intro").is_file() else []) + [p for *_, p in sorted(turns)]
    if not files:
        raise DataError(f"{session_dir}: no raw recordings (intro, robot_N, user_N) found; "
                        "give a session folder of the raw published layout (raw_sessions.tar.xz)")
    return files


class ReplayMuse(_Publisher):
    """Replays a recorded raw session as a live 4-channel EEG stream: a folder written by ``nao-trainer run``
    (its ``eeg/raw.csv``, at the recorded stream's rate), a study folder of them (one after another), or
    a raw session of the published layout (220 Hz)."""

    acquisition = "replayed"
    data: np.ndarray
    boundaries: list[tuple[str, int]]  # (file name, index of its first sample)
    _pos: int = 0
    loop: bool = False

    @classmethod
    def start(cls, session_dir: Path, *, name: str = "Muse", source_id: str | None = None,
              fs: float = RAW_RATE_HZ, chunk: int = MUSE_CHUNK, loop: bool = False,
              wall_clock: bool = False, scope: str = "machine") -> "ReplayMuse":
        """Read every raw file of ``session_dir`` (errors name file:line) and start publishing."""
        session_dir = Path(session_dir)
        labels: tuple[str, ...] = CHANNELS
        if is_own_session(session_dir):
            data, boundaries, fs, labels = load_own_session(session_dir)
        elif not (session_dir / "state_EEG").exists() and find_own_sessions(session_dir):
            data, boundaries, fs, labels = load_own_study(session_dir)
        else:
            data, boundaries = load_raw_session(session_dir)
        sid = source_id or f"Muse-replay-{session_dir.parent.name}-{session_dir.name}"
        rep = cls(name=name, source_id=sid, labels=labels, fs=float(fs), chunk=int(chunk),
                  wall_clock=wall_clock, scope=scope)
        rep.data, rep.boundaries, rep.loop = data, boundaries, loop
        rep.origin = str(session_dir.resolve())
        rep._open_outlet()
        rep._start_thread()
        return rep

    def _samples(self, n: int) -> np.ndarray | None:
        if self._pos >= len(self.data):
            if not self.loop:
                return None
            self._pos = 0
        x = self.data[self._pos : self._pos + n]
        self._pos += len(x)
        return x


def load_raw_session(session_dir: Path) -> tuple[np.ndarray, list[tuple[str, int]]]:
    """All ``eeg`` samples of a raw session in recording order, with each file's start index.

    A malformed ``eeg`` line raises DataError naming file and line (:func:`nao_trainer.data.published.read_recording`).
    """
    parts, boundaries, start = [], [], 0
    for path in raw_recording_order(session_dir):
        x = read_recording(path, prefixes=("eeg",))["eeg"]
        boundaries.append((path.name, start))
        parts.append(x)
        start += len(x)
    data = np.concatenate(parts) if parts else np.empty((0, 4))
    if len(data) == 0:
        raise DataError(f"{session_dir}: the raw recordings hold no 'eeg' lines (band-only files?); "
                        "replay needs the raw layout with 'eeg' lines")
    return data, boundaries


def load_own_session(session_dir: Path) -> tuple[np.ndarray, list[tuple[str, int]], float, tuple[str, ...]]:
    """The scalp samples a ``nao-trainer run`` session saved (``eeg/raw.csv``), its rate and channel names."""
    eeg = Path(session_dir) / "eeg"
    if not (eeg / "raw.csv").is_file():
        raise DataError(f"{session_dir}: no eeg/raw.csv to replay (EEG was off, or eeg.processing.record_raw false)")
    stream = read_json(eeg / "stream.json", DataError)
    labels = tuple(stream.get("scalp_channels") or CHANNELS)
    fs = float(stream.get("nominal_srate") or 0)
    if fs <= 0:
        raise DataError(f"{eeg / 'stream.json'}: nominal_srate must be > 0 to replay")
    data, _ts, _notes = read_raw(eeg / "raw.csv", len(labels))
    if len(data) == 0:
        raise DataError(f"{eeg / 'raw.csv'}: no samples to replay")
    return data, [("eeg/raw.csv", 0)], fs, labels


def load_own_study(study_dir: Path) -> tuple[np.ndarray, list[tuple[str, int]], float, tuple[str, ...]]:
    """Every session of a study folder with saved EEG, one after another (they must share rate and channels).

    Sessions without ``eeg/raw.csv`` are passed over; DataError when none has EEG.
    """
    parts, boundaries, start, shape = [], [], 0, None
    for folder in find_own_sessions(study_dir):
        if not (folder / "eeg" / "raw.csv").is_file():
            continue
        data, _b, fs, labels = load_own_session(folder)
        if shape is None:
            shape = (fs, labels)
        elif (fs, labels) != shape:
            raise DataError(f"{folder}: recorded at {fs:g} Hz with {'/'.join(labels)}, the study's first session at "
                            f"{shape[0]:g} Hz with {'/'.join(shape[1])}; replay the sessions one by one")
        boundaries.append((f"{folder.name}/eeg/raw.csv", start))
        parts.append(data)
        start += len(data)
    if shape is None:
        raise DataError(f"{study_dir}: no session with eeg/raw.csv to replay")
    return np.concatenate(parts), boundaries, shape[0], shape[1]
