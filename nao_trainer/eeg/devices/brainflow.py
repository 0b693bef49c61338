"""BrainFlow headbands: the Muse 2 and Muse S (Bluetooth LE, or the BLED112 dongle), and BrainFlow's
synthetic board, read with the ``brainflow`` package (``pip install 'nao-trainer[brainflow]'``).

Registered as EEG device ``brainflow`` (``registry.BUILTIN``). The board is read in this process and its
EEG channels are **republished to an LSL outlet** on this machine (``eeg.lsl_scope``), pinned by a
unique source_id. Why republish rather than read BrainFlow inside the monitor: the monitor, its
reconnection and gap records, ``check``, the session's LSL marker stream and the ``session.xdf``
recorder (LabRecorder's engine, which records LSL streams only) then stay one path for every headband;
the cost is one in-process copy of a 256 Hz, 4-channel stream. Markers therefore go where they go for
a Muse over LSL, the project's marker stream, and so into ``session.xdf`` on the same clock; BrainFlow's
``insert_marker`` is not used (its marker channel is not republished: the XDF has the markers already).

``eeg.mode: simulated`` (or ``device_settings.board: synthetic``) plays BrainFlow's synthetic board: the
real library path (``BoardShim``, ``prepare_session``, ``get_board_data``) with generated data; its stream
says ``acquisition: synthetic``, so a session where a person answers refuses it like a simulated Muse.

A board that stops delivering (a Muse dropout, Bluetooth out of range) is reconnected in the background:
after ``reconnect_after_s`` without data the session is released and prepared again, with a growing
pause between attempts, while the outlet stays, so the monitor records one gap and attaches again by
itself when the samples return.
"""
from __future__ import annotations

import itertools
import logging
import os
import threading
import time
from typing import Any

from nao_trainer.core.engagement import QualityThresholds
from nao_trainer.core.montage import Montage
from nao_trainer.core.settings import setting, settings
from nao_trainer.eeg.device import EEGDevice, Source
from nao_trainer.eeg.inlet import StreamQuery  # pylsl-free (pylsl loads when a stream is opened)
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.errors import EEGUnavailable

log = logging.getLogger(__name__)

#: Board names a study may use, with BrainFlow's board id (``brainflow.board_shim.BoardIds``).
BOARDS: dict[str, int] = {
    "synthetic": -1,  # BoardIds.SYNTHETIC_BOARD: generated data through the real library
    "muse_2": 38,  # BoardIds.MUSE_2_BOARD: native Bluetooth LE
    "muse_s": 39,  # BoardIds.MUSE_S_BOARD
    "muse_2_bled": 22,  # BoardIds.MUSE_2_BLED_BOARD: through the BLED112 dongle (serial_port)
    "muse_s_bled": 21,  # BoardIds.MUSE_S_BLED_BOARD
}
SYNTHETIC = "synthetic"
_COUNTER = itertools.count(1)


def _board(value: Any) -> str | None:
    if isinstance(value, str) and value not in BOARDS:
        return f"must be one of {', '.join(BOARDS)} or a BrainFlow board id (an integer)"
    return None


@settings
class BrainFlowSettings:
    """``eeg.device_settings`` of the ``brainflow`` device."""

    board: Any = setting(SYNTHETIC, kind=(str, int), check=_board,
                         doc="synthetic | muse_2 | muse_s | muse_2_bled | muse_s_bled, or a BrainFlow board id")
    mac_address: str | None = setting(None, kind=str, nullable=True, doc="the headband's MAC (BLE boards; null = first found)")
    serial_number: str | None = setting(None, kind=str, nullable=True, doc="the headband's name, e.g. Muse-1A2B")
    serial_port: str | None = setting(None, kind=str, nullable=True,
                                      doc="the BLED112 dongle's port (*_bled boards), e.g. /dev/ttyACM0 or COM3")
    timeout_s: int = setting(15, kind=int, min=1, max=120, doc="how long BrainFlow looks for the headband, s")
    channels: tuple | None = setting(None, kind=list, item=str, nullable=True,
                                     doc="EEG channels analysed (null = the board's, at most its first four)")
    reconnect_after_s: float = setting(2.0, kind=(int, float), min=0.2, max=60.0,
                                       doc="no data this long: release and reconnect the board, s")
    min_std_uv: float = setting(1.0, kind=(int, float), min=0.0, max=1000.0, doc="below: flat, uV")
    max_std_uv: float = setting(100.0, kind=(int, float), above=0.0, max=100000.0, doc="above: implausible, uV")
    max_ptp_uv: float = setting(600.0, kind=(int, float), above=0.0, max=100000.0, doc="peak-to-peak above: implausible, uV")

    def __post_init__(self) -> None:
        QualityThresholds(self.min_std_uv, self.max_std_uv, self.max_ptp_uv)


def _shim():
    try:
        from brainflow.board_shim import BoardShim, BrainFlowError, BrainFlowInputParams
    except ImportError as exc:
        raise EEGUnavailable(f"EEG device 'brainflow' needs the brainflow package ({exc}); "
                             "pip install 'nao-trainer[brainflow]'") from None
    return BoardShim, BrainFlowInputParams, BrainFlowError


class BrainFlowDevice(EEGDevice):
    """A Muse 2 / Muse S (BLE or BLED112) or BrainFlow's synthetic board, read with brainflow, republished to LSL."""

    Settings = BrainFlowSettings
    opens_in_process = True
    start_hint = ("switch the headband on and bring it near (Bluetooth on; the BLED112 dongle at "
                  "eeg.device_settings.serial_port for *_bled boards)")

    def board_id(self, simulated: bool) -> int:
        board = SYNTHETIC if simulated else self.settings.board
        return BOARDS[board] if isinstance(board, str) else int(board)

    def montage(self, simulated: bool = False) -> Montage:
        BoardShim, _, BrainFlowError = _shim()
        board_id = self.board_id(simulated)
        try:
            names = [n.strip() for n in BoardShim.get_eeg_names(board_id)]
            rate = float(BoardShim.get_sampling_rate(board_id))
            title = BoardShim.get_board_descr(board_id).get("name", str(board_id))
        except BrainFlowError as exc:
            raise EEGUnavailable(f"BrainFlow board {board_id}: not an EEG board this brainflow knows ({exc}); "
                                 f"set eeg.device_settings.board to one of {', '.join(BOARDS)}") from None
        wanted = self.settings.channels
        if wanted:
            missing = [c for c in wanted if c not in names]
            if missing:
                raise EEGUnavailable(f"eeg.device_settings.channels: board {title} has no {', '.join(missing)}; "
                                     f"its EEG channels are {', '.join(names)}")
            labels = tuple(wanted)
        else:
            labels = tuple(names[:4])
        s = self.settings
        return Montage(self.name, labels, rate, QualityThresholds(s.min_std_uv, s.max_std_uv, s.max_ptp_uv),
                       prefer_name="BrainFlow", board=f"BrainFlow {title} board (id {board_id})")

    def open(self, eeg, rng, *, simulated: bool, rest_target: float = 0.5) -> Source:
        montage = self.montage(simulated)
        bridge = BrainFlowBridge(self.board_id(simulated), self.settings, montage, eeg.lsl_scope)
        bridge.start(required=bool(eeg.required) or simulated)
        return Source(StreamQuery(eeg.stream_type, None, bridge.source_id, montage.prefer_name), montage, bridge)


class BrainFlowBridge:
    """Reads a BrainFlow board in a thread and pushes its EEG channels to an LSL outlet; reconnects."""

    def __init__(self, board_id: int, s: BrainFlowSettings, montage: Montage, scope: str) -> None:
        BoardShim, Params, self._Error = _shim()
        BoardShim.disable_board_logger()  # its log goes to stderr; failures are reported here, in one line
        self._BoardShim, self._Params = BoardShim, Params
        self.board_id, self.s, self.montage, self.scope = board_id, s, montage, scope
        names = [n.strip() for n in BoardShim.get_eeg_names(board_id)]
        rows = BoardShim.get_eeg_channels(board_id)
        self._rows = [rows[names.index(label)] for label in montage.labels]
        self._ts_row = BoardShim.get_timestamp_channel(board_id)
        self.synthetic = board_id == BOARDS[SYNTHETIC]
        who = s.mac_address or s.serial_number or s.serial_port or "any"
        board = next((name for name, bid in BOARDS.items() if bid == board_id), f"board{board_id}")
        self.source_id = f"brainflow-{board}-{who}-{os.getpid()}-{next(_COUNTER)}"
        self.board: Any = None
        self.samples_pushed = 0
        self.reconnects = 0  # sessions prepared again after the board went silent
        self.last_error = ""
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._outlet: Any = None
        self._thread: threading.Thread | None = None

    # -- life -------------------------------------------------------------------------------------

    def start(self, required: bool) -> None:
        """Open the outlet and connect the board. A board not found: ``EEGUnavailable`` when ``required``,
        else the bridge keeps trying in the background (the session records a gap until it connects)."""
        self._open_outlet()
        if not self._connect() and required:
            self.stop()
            raise EEGUnavailable(f"{self.montage.board} could not be opened: {self.last_error}; "
                                 f"{BrainFlowDevice.start_hint}, or run with --eeg off")
        if self.board is None:
            log.warning("%s not connected yet (%s); the session keeps trying", self.montage.board, self.last_error)
        self._thread = threading.Thread(target=self._run, name=f"brainflow-{self.board_id}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop reading, release the board, destroy the outlet (inlets see the stream end)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._release()
        self._outlet = None

    def interrupt(self) -> None:
        """Stop the board's stream underneath the bridge, as a headband that drops out (tests, demos):
        the bridge sees no data and reconnects by itself."""
        with self._lock:
            if self.board is not None:
                self.board.stop_stream()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- board ------------------------------------------------------------------------------------

    def _params(self):
        p = self._Params()
        p.mac_address = self.s.mac_address or ""
        p.serial_number = self.s.serial_number or ""
        p.serial_port = self.s.serial_port or ""
        p.timeout = int(self.s.timeout_s)
        return p

    def _connect(self) -> bool:
        board = self._BoardShim(self.board_id, self._params())
        try:
            board.prepare_session()
            board.start_stream(45000)
        except self._Error as exc:
            self.last_error = str(exc)
            try:
                board.release_session()
            except self._Error:
                pass
            return False
        with self._lock:
            self.board = board
        return True

    def _release(self) -> None:
        with self._lock:
            board, self.board = self.board, None
        if board is not None:
            try:
                board.release_session()
            except self._Error:
                pass
        del board  # collected now, before a new session of the same board exists (see _read)

    def _open_outlet(self) -> None:
        configure_lsl(self.scope)
        import pylsl

        m = self.montage
        info = pylsl.StreamInfo("BrainFlow", "EEG", len(m.labels), m.rate_hz, pylsl.cf_float32, self.source_id)
        desc = info.desc()
        desc.append_child_value("manufacturer", "BrainFlow")
        desc.append_child_value("board", m.board)
        desc.append_child_value("acquisition", "synthetic" if self.synthetic else "")
        channels = desc.append_child("channels")
        for label in m.labels:
            ch = channels.append_child("channel")
            ch.append_child_value("label", label)
            ch.append_child_value("unit", "microvolts")
            ch.append_child_value("type", "EEG")
        self._outlet = pylsl.StreamOutlet(info, 12, 360)

    def has_consumers(self) -> bool:
        outlet = self._outlet
        return bool(outlet is not None and outlet.have_consumers())

    # -- thread -----------------------------------------------------------------------------------

    def _read(self):
        """The board's new samples (rows x n), or None. No reference to the board outlives this call:
        ``BoardShim.__del__`` releases *any* prepared session of the same board and parameters, so an old
        object collected after a reconnection would end the new session."""
        with self._lock:
            if self.board is None:
                return None
            try:
                return self.board.get_board_data()
            except self._Error as exc:
                self.last_error = str(exc)
                return None

    def _run(self) -> None:
        import numpy as np
        import pylsl

        wall_offset = time.time() - pylsl.local_clock()  # BrainFlow stamps with UNIX time
        last_data = time.monotonic()
        pause = 0.5
        while not self._stop.wait(0.05):
            data = self._read()
            if data is not None and data.shape[1]:
                x = np.ascontiguousarray(data[self._rows].T, dtype=np.float32)
                self._outlet.push_chunk(x, float(data[self._ts_row, -1]) - wall_offset)
                self.samples_pushed += x.shape[0]
                last_data, pause = time.monotonic(), 0.5
                continue
            if time.monotonic() - last_data < self.s.reconnect_after_s:
                continue
            # silent too long: release and prepare the session again, waiting longer after each failure
            self._release()
            if self._connect():
                self.reconnects += 1
                log.warning("%s reconnected (%d)", self.montage.board, self.reconnects)
                last_data = time.monotonic()
            else:
                self._stop.wait(pause)
                pause = min(pause * 2, 10.0)
