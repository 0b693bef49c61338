"""The live engagement monitor: an EEG stream over LSL turned into per-phase engagement for a session.

``LslMonitor`` implements ``ports.EngagementMonitor`` over one EEG stream; ``eeg.factory.open_monitor``
builds it (or a ``NullMonitor``) from the study's settings.

A background thread pulls chunks, feeds ``core.engagement.OnlineEngagement`` (sliding windows,
band powers, EWMA) and keeps the window results on the local LSL clock. Phases are delimited by
``local_clock()`` at ``begin_phase`` / ``end_phase``; ``end_phase`` aggregates the windows that end
inside the phase (``core.engagement.aggregate_phase``). Normalisation: an ``EngagementNormaliser``
whose reference is the baseline phase (greeting and instructions) and whose running bounds are taken
over the task phases' windows. Without a baseline the task's bounds alone apply, so the first phases
have no normalised value until enough windows were seen (``engagement`` None, ``index`` still given).

Nothing is invented: a phase without enough clean signal returns ``engagement=None`` with the
reason. A stream that stops delivering for ``loss_timeout_s`` is marked lost (event, gap record);
the inlet reconnects by itself when a stream with the same source_id returns, and the gap is
closed. Files in ``<session>/eeg/``: ``stream.json``, ``events.csv``, ``windows.csv``,
``phases.csv``, ``gaps.csv`` and ``raw.csv`` (scalp samples with LSL stamps), all flushed as written.
Values and stamps are written at full precision, and each phase row names the last sample the phase
saw, so ``data/own.py`` recomputes every phase from ``raw.csv`` exactly. With ``record_xdf`` the
session's EEG and marker streams also go to ``<session>/session.xdf`` (``eeg/xdf.py``).
"""
from __future__ import annotations

import logging
import threading
import time as _time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from nao_trainer.core.engagement import OnlineEngagement, WindowResult
from nao_trainer.core.montage import Montage
from nao_trainer.core.phase import EngagementNormaliser, summarise_phase
from nao_trainer.eeg.inlet import EEGInlet, StreamQuery
from nao_trainer.eeg.settings import EEGSettings, simulated_refusal
from nao_trainer.eeg.markers import MarkerOutlet, event_name
from nao_trainer.eeg.session_files import (EVENTS_HEADER, GAPS_HEADER, PHASES_HEADER, SEGMENTS_HEADER, WINDOWS_HEADER,
                                           SessionFiles, fmt)
from nao_trainer.eeg.xdf import XdfRecorder, XdfUnavailable, truncation
from nao_trainer.ports import PhaseEngagement

log = logging.getLogger(__name__)

PHASES = ("baseline", "listening", "answer")
#: Longest wait at the session start for the session.xdf recorder to connect (about 1.5 s on an idle laptop).
XDF_WAIT_S = 30.0


# ----------------------------------------------------------------------------------------------
# The monitor
# ----------------------------------------------------------------------------------------------


@dataclass
class _Phase:
    name: str
    turn: int | None
    t0: float
    last_sample: float | None = None  # stamp of the last sample processed when the phase was summarised


@dataclass
class Gap:
    """A period without samples: ``end`` is None while it lasts."""

    start: float
    end: float | None = None
    kind: str = "stream lost"

    def overlap(self, t0: float, t1: float, now: float) -> float:
        end = now if self.end is None else self.end
        return max(0.0, min(t1, end) - max(t0, self.start))


class LslMonitor:
    """``ports.EngagementMonitor`` over one LSL EEG stream. Build it with :func:`open_monitor`."""

    def __init__(self, settings: EEGSettings, query: StreamQuery, session_dir: Path | None,
                 inlet: EEGInlet | None, markers: MarkerOutlet | None, unavailable_reason: str = "",
                 simulator=None, record_xdf: bool = False, refuse_simulated: bool = False,
                 montage: Montage | None = None) -> None:
        import pylsl

        self._clock = pylsl.local_clock
        self._started = self._clock()  # names this monitor in phases.csv / segments.csv
        self._segment_open = False  # the current estimator's first sample is in segments.csv
        self.settings = settings
        self.proc = settings.processing
        self.query = query
        # the device's channels, rate and quality thresholds (eeg.device); a Muse's when not given
        self.montage = montage if montage is not None else settings.eeg_device().montage()
        self.files = SessionFiles(session_dir)
        self.markers = markers
        self.simulator = simulator
        self.inlet: EEGInlet | None = None
        self.engine: OnlineEngagement | None = None
        self.normaliser = EngagementNormaliser()
        self.windows: list[WindowResult] = []
        self.gaps: list[Gap] = []
        self.phases: list[tuple[_Phase, float, PhaseEngagement]] = []
        self.unavailable_reason = unavailable_reason
        self.errors = 0
        self.samples_received = 0
        self.thread_cpu_s = 0.0  # CPU time of the reader thread (benchmarks)
        self._phase: _Phase | None = None
        self._had_baseline = False  # a baseline phase was summarised (for the no-scale reason)
        self._resolver = None  # a pylsl.ContinuousResolver while waiting for a stream
        self._rejected: set[str] = set()  # source_ids found but unusable
        self.refuse_simulated = refuse_simulated  # a person's session: never attach a simulated/replayed stream
        self.stream_identity: dict | None = None  # EEGInlet.identity() of the stream attached (session.json)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._urgent = threading.Event()  # set while end_phase waits for samples in flight
        self._last_arrival = self._clock()
        self._last_stamp = -np.inf
        self._raw_pending: list[np.ndarray] = []
        self._raw_lock = threading.Lock()
        self._raw_n = 0
        self._lost = False
        self._closed = False
        self.xdf = None  # the session.xdf recorder (eeg.xdf.XdfRecorder) once a stream is attached
        self.xdf_problem = ""  # why session.xdf is not whole (cut by a full disk), once stopped
        self._xdf_wanted = record_xdf and settings.xdf and session_dir is not None and markers is not None
        if inlet is not None:
            self._attach(inlet)
        self._thread = threading.Thread(target=self._run, name="eeg-monitor", daemon=True)
        self._thread.start()
        if inlet is not None:
            self._start_xdf()  # before the session's first marker; the reader already runs meanwhile

    # -- state --------------------------------------------------------------------------------

    @property
    def records_eeg(self) -> bool:
        """Always: this monitor records EEG (``ports.EngagementMonitor``), even while the stream is away."""
        return True

    @property
    def available(self) -> bool:
        """True while a stream is attached and delivering."""
        return self.inlet is not None and not self._lost

    def describe(self) -> str:
        """The stream in use (``ports.EngagementMonitor``), or why there is none yet."""
        inlet = self.inlet
        if inlet is None:
            return "no stream yet; the session keeps looking for one and uses it from then on"
        return (f"stream {inlet.name!r} (source_id {inlet.source_id!r}, {inlet.fs:g} Hz, channels "
                f"{'/'.join(inlet.scalp_labels)})")

    @property
    def status(self) -> str:
        if self.inlet is None:
            return "unavailable"
        return "lost" if self._lost else "streaming"

    def live(self) -> dict | None:
        """Latest index and per-channel contact (``ports.EngagementMonitor.live``); reads only, any thread."""
        windows, engine = self.windows, self.engine
        last = windows[-1] if windows else None
        clean = getattr(engine, "last_clean", None) if engine is not None else None
        return {
            "status": self.status,
            "index": None if last is None or last.index_smoothed is None else round(float(last.index_smoothed), 4),
            "clean_fraction": None if last is None else round(float(last.clean_fraction), 3),
            "channels": {} if clean is None else {str(n): bool(c) for n, c in zip(engine.channel_names, clean)},
            "reason": "" if last is None else last.reason,
        }

    def _attach(self, inlet: EEGInlet) -> None:
        self.inlet = inlet
        self._segment_open = False
        p = self.proc
        self.engine = OnlineEngagement(
            inlet.fs, len(inlet.scalp_index), window_s=p.window_s, hop_s=p.hop_s, a=p.ewma_a,
            thresholds=self.montage.thresholds, min_clean_channels=min(p.min_clean_channels, len(inlet.scalp_index)),
            gap_factor=max(2.0, p.gap_tolerance_s * inlet.fs), channel_names=inlet.scalp_labels)
        self.unavailable_reason = ""
        self._last_arrival = self._clock()
        self.stream_identity = inlet.identity()
        self.files.write_json("stream.json", {**inlet.describe(), "lsl_scope": self.settings.lsl_scope,
                                              "processing": asdict(self.proc), "device": self.montage.device,
                                              "montage": self.montage.to_dict()})
        self._event("eeg_stream_found", f"{inlet.name} {inlet.source_id} {inlet.fs:g} Hz "
                                        f"{'/'.join(inlet.scalp_labels)}")

    def _start_xdf(self) -> None:
        """Record ``session.xdf`` (this EEG stream and the marker stream); without it, say why and go on.

        Returns once the recorder's marker inlet is connected: a marker pushed earlier would be lost.
        """
        if not self._xdf_wanted or self.xdf is not None or self.inlet is None:
            return
        self._xdf_wanted = False
        path = self.files.dir.parent / "session.xdf"
        for k in range(2, 1000):  # a resumed session keeps the first file: session_2.xdf, ...
            if not path.exists():
                break
            path = path.with_name(f"session_{k}.xdf")
        try:
            self.xdf = XdfRecorder.start(path, [self.inlet.source_id, self.markers.source_id],
                                         self.settings.lsl_scope, log_path=self.files.dir / "xdf.log",
                                         ready=self.markers.has_consumers, timeout_s=XDF_WAIT_S)
        except XdfUnavailable as exc:
            log.warning("%s", exc)
            self._event("xdf_unavailable", str(exc), publish=False)
            return
        if not self.xdf.ready:  # a loaded machine: the session does not wait longer; the file starts later
            log.warning("session.xdf: the recorder is still connecting; events before it connects are not in the file")
            self._event("xdf_late", f"{path.name}: recorder not connected after {XDF_WAIT_S:g} s; "
                        "recording from when it connects", publish=False)
            return
        self._event("xdf_recording", f"{path.name}: {self.inlet.source_id} + {self.markers.source_id}", publish=False)

    def _stop_xdf(self) -> None:
        """Finish session.xdf while the streams still run (the recorder keeps their last chunks)."""
        if self.xdf is None:
            return
        code = self.xdf.stop()
        self._event("xdf_stopped" if code == 0 else "xdf_failed", f"exit {code} (log: eeg/xdf.log)", publish=False)
        if code != 0:
            log.warning("session.xdf: the recorder ended with exit code %s; see %s", code, self.xdf.log_path)
        cut = truncation(self.xdf.path) if code == 0 else None
        if cut is not None:  # a full disk or a file size limit: the engine itself reports nothing
            self.xdf_problem = (f"{self.xdf.path}: {cut} (a full disk or a file size limit); free some space or "
                                "raise the limit (ulimit -f); eeg/raw.csv records the same EEG")
            log.warning("%s", self.xdf_problem)
            self._event("xdf_incomplete", self.xdf_problem, publish=False)

    def _event(self, event: str, detail: str = "", turn: int | None = None, publish: bool = True) -> float:
        name = event_name(event, turn)
        stamp = self.markers.push(name) if (publish and self.markers is not None) else 0.0
        stamp = stamp or self._clock()
        self.files.write("events.csv", EVENTS_HEADER, [[f"{stamp:.6f}", name, detail]])
        return stamp

    # -- reader thread --------------------------------------------------------------------------

    def _run(self) -> None:
        cpu0 = _time.thread_time()
        consecutive = 0
        while not self._stop.is_set():
            try:
                if self.inlet is None:
                    self._try_resolve()
                else:
                    self._pull_once()
                consecutive = 0
            except Exception as exc:  # no exception may escape: log, count, mark, carry on
                consecutive += 1
                self.errors += 1
                log.warning("EEG monitor: %s: %s", type(exc).__name__, exc)
                self.files.write("events.csv", EVENTS_HEADER,
                                 [[f"{self._clock():.6f}", "eeg_error", f"{type(exc).__name__}: {exc}"]])
                if consecutive >= 20:
                    self.unavailable_reason = f"EEG reader failed repeatedly ({type(exc).__name__}: {exc})"
                    self._mark_lost("reader failed")
                    self._stop.wait(1.0)
                else:
                    self._stop.wait(0.05)
            self.thread_cpu_s = _time.thread_time() - cpu0

    def _try_resolve(self) -> None:
        """No stream yet: watch for one in the background (a continuous resolver) and attach to it."""
        if self._resolver is None:
            import pylsl

            self._resolver = pylsl.ContinuousResolver(pred=self.query.predicate(), forget_after=5.0)
        infos = [i for i in self._resolver.results() if i.source_id() not in self._rejected]
        if infos and not self._stop.is_set():
            info = self.query.pick(infos)
            try:
                inlet = EEGInlet.open(info, self.settings.lsl_scope, montage=self.montage)
            except Exception as exc:  # not usable (e.g. irregular rate): say so once, keep looking
                self._rejected.add(info.source_id())
                self._event("eeg_stream_rejected", f"{info.name()} {info.source_id()}: {exc}", publish=False)
                return
            refusal = simulated_refusal(inlet.identity(), self.settings) if self.refuse_simulated else ""
            if refusal:  # a simulate-muse appearing mid-session is not the participant's headband
                inlet.close()
                self._rejected.add(info.source_id())
                log.warning("%s", refusal)
                self._event("eeg_stream_rejected", f"{info.name()} {info.source_id()}: {refusal}", publish=False)
                return
            self._attach(inlet)
            self._resolver = None
            self._start_xdf()  # a stream that appeared late: recorded from now on
        else:
            self._stop.wait(0.5)

    def _pull_once(self) -> None:
        # Between phase ends: drain the inlet every poll_s (cheap). While end_phase waits: short
        # blocking pulls, so samples up to the phase end are processed as soon as they arrive.
        if self._urgent.wait(self.proc.poll_s):
            x, ts = self.inlet.pull(0.005)
        else:
            x, ts = self.inlet.pull(0.0)
        now = self._clock()
        if len(ts) == 0:
            if not self._lost and now - self._last_arrival > self.proc.loss_timeout_s:
                self._mark_lost("no samples for %.1f s" % (now - self._last_arrival))
            return
        results = self.engine.push(x, ts)
        if not self._segment_open:  # a new estimator started here: an offline replay starts one here too
            self._segment_open = True
            self.files.write("segments.csv", SEGMENTS_HEADER, [[repr(float(ts[0])), repr(self._started)]])
        if self.proc.record_raw:
            self._record_raw(x, ts)
        with self._cond:
            if self._lost:
                self._mark_restored(float(ts[0]))
            self._last_arrival = now
            self._last_stamp = float(ts[-1])
            self.samples_received += len(ts)
            self.windows.extend(results)
            self._prune()
            self._cond.notify_all()

    def _record_raw(self, x: np.ndarray, ts: np.ndarray, force: bool = False) -> None:
        """Append scalp samples to ``eeg/raw.csv`` in blocks of about a second (never more unwritten).

        ``force`` (a phase end, the close) writes what is pending: a phase's row in phases.csv is never on
        disk before the samples it was computed from, so even a killed session's phases replay exactly.
        """
        if self.inlet is None:
            return
        with self._raw_lock:  # the reader thread appends, a phase end flushes
            self._record_raw_locked(x, ts, force)

    def _flush_raw(self) -> None:
        if self._raw_pending:
            self._record_raw(np.empty((0, len(self.inlet.scalp_index))), np.empty(0), force=True)

    def _record_raw_locked(self, x: np.ndarray, ts: np.ndarray, force: bool) -> None:
        if len(ts):
            self._raw_pending.append(np.column_stack([ts, x]))
            self._raw_n += len(ts)
        if not self._raw_pending or not (force or self._raw_n >= self.inlet.fs):
            return
        labels = list(self.inlet.scalp_labels)
        log_ = self.files.log("raw.csv", ["lsl_time", *labels])
        block = np.concatenate(self._raw_pending)
        self._raw_pending, self._raw_n = [], 0
        if log_ is None:
            return
        row = ",".join(["%r"] * (1 + len(labels))) + "\n"  # exact: the offline re-analysis replays these
        with self.files.lock:
            fh = log_.raw_file()
            try:
                fh.write((row * len(block)) % tuple(block.ravel().tolist()))  # one format op: cheap
                fh.flush()
            except OSError as exc:  # name the file: a full disk fails in write(), which names none
                raise OSError(exc.errno, exc.strerror, str(log_.path)) from exc

    def _prune(self) -> None:
        """Forget windows no open phase can still need (keeps ``end_phase`` cheap in long sessions)."""
        if len(self.windows) > 4000:
            horizon = (self._phase.t0 if self._phase else self._last_stamp) - 60.0
            self.windows = [w for w in self.windows if w.t_end > horizon]

    def _mark_lost(self, why: str) -> None:
        with self._cond:
            if self._lost or self.inlet is None:  # nothing attached: already "unavailable"
                return
            self._lost = True
            start = self._last_stamp if np.isfinite(self._last_stamp) else self._clock()
            self.gaps.append(Gap(start))
            # Logged and published before the lock goes, as ``_mark_restored`` does: the reader cannot close
            # the gap (and publish "restored") before "lost" is out (seen on a loaded machine: the restored
            # marker first, the lost one after the recorder had stopped).
            log.warning("EEG stream %r lost (%s); waiting for it to return", self.inlet.name, why)
            self._event("eeg_stream_lost", why)
            self._cond.notify_all()

    def _mark_restored(self, first_stamp: float) -> None:
        """Called with ``_cond`` held when samples arrive again after a loss."""
        self._lost = False
        gap = self.gaps[-1]
        gap.end = first_stamp
        self.files.write("gaps.csv", GAPS_HEADER,
                         [[f"{gap.start:.6f}", f"{gap.end:.6f}", f"{gap.end - gap.start:.3f}", gap.kind]])
        log.warning("EEG stream %r is back after %.1f s", self.inlet.name, gap.end - gap.start)
        self._event("eeg_stream_restored", f"gap {gap.end - gap.start:.3f} s")

    def wait_for_windows(self, n: int, timeout_s: float) -> bool:
        """Block until ``n`` analysis windows exist (e.g. before a baseline); False on timeout."""
        deadline = self._clock() + timeout_s
        with self._cond:
            while len(self.windows) < n:
                remaining = deadline - self._clock()
                if remaining <= 0 or self.inlet is None:
                    return False
                self._cond.wait(remaining)
            return True

    def wait_available(self, timeout_s: float) -> bool:
        """Block until the stream delivers again (after a loss) or ``timeout_s`` passes; True if it does."""
        deadline = self._clock() + timeout_s
        with self._cond:
            while not self.available and not self._closed:
                remaining = deadline - self._clock()
                if remaining <= 0:
                    return False
                self._cond.wait(min(remaining, 0.5))
            return self.available

    def gap_report(self) -> list[dict]:
        """Each gap for session.json: its LSL start and end (None: lasted to the end), its length, and the
        turns whose phases it overlapped."""
        now = self._clock()
        out = []
        for g in list(self.gaps):
            turns = sorted({ph.turn for ph, t1, _ in self.phases if ph.turn is not None and g.overlap(ph.t0, t1, now) > 0})
            out.append({"start": round(g.start, 6), "end": None if g.end is None else round(g.end, 6),
                        "duration_s": None if g.end is None else round(g.end - g.start, 3),
                        "until_end": g.end is None, "kind": g.kind, "turns": turns})
        return out

    # -- EngagementMonitor ----------------------------------------------------------------------

    def mark(self, event: str, turn: int | None = None) -> None:
        """Publish a session event on the marker stream and log it to ``eeg/events.csv``."""
        self._event(event, "", turn)

    def set_target(self, engagement: float | None) -> None:
        """Drive the simulated Muse (simulated mode); ignored for a real headband, a BrainFlow board or None."""
        follow = getattr(self.simulator, "set_target", None)  # a BrainFlow board does not follow
        if follow is not None and engagement is not None:
            follow(float(np.clip(engagement, 0.0, 1.0)))

    def begin_phase(self, phase: str, turn: int | None) -> None:
        """Open a phase ("baseline", "listening" or "answer") now, on the LSL clock.

        Phase markers are not published here: the session calls ``mark("<phase>_start", turn)``.
        """
        if phase not in PHASES:
            raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {phase!r}")
        if self._phase is not None:
            log.warning("EEG phase %s of turn %s was not ended; discarding it", self._phase.name, self._phase.turn)
        # The session publishes the phase markers itself (mark("listening_start", turn)), right after.
        self._phase = _Phase(phase, turn, self._clock())

    def end_phase(self) -> PhaseEngagement:
        """Close the open phase and return its engagement (or why there is none)."""
        ph = self._phase
        if ph is None:
            return PhaseEngagement(None, None, 0.0, "no EEG phase was open")
        t1 = self._clock()
        windows = self._windows_until(ph.t0, t1)
        self._phase = None  # only now: until the windows are collected, _prune keeps the whole phase
        result, rows = self._summarise(ph, t1, windows)
        self.phases.append((ph, t1, result))
        self._flush_raw()  # the phase's samples reach the disk before its row
        self._write_phase(ph, t1, result, rows)
        return result

    def _windows_until(self, t0: float, t1: float) -> list[WindowResult]:
        """The phase's windows, after waiting (at most ``end_wait_s``) for samples still in flight."""
        deadline = t1 + self.proc.end_wait_s
        hop = self.proc.hop_s
        with self._cond:
            try:
                while self.available:
                    # done once samples reach t1, or once the next window would end after t1 anyway
                    done = self._last_stamp >= t1 or bool(self.windows and self.windows[-1].t_end + hop > t1 + 1e-3)
                    remaining = deadline - self._clock()
                    if done or remaining <= 0:
                        break
                    self._urgent.set()
                    self._cond.wait(remaining)
            finally:
                self._urgent.clear()
            if self._phase is not None and np.isfinite(self._last_stamp):
                # every window up to this sample was computed: an offline replay selects the same ones
                self._phase.last_sample = self._last_stamp
            return [w for w in self.windows if t0 < w.t_end <= t1]

    def _summarise(self, ph: _Phase, t1: float, windows: list[WindowResult]):
        now = self._clock()
        lost_s = sum(g.overlap(ph.t0, t1, now) for g in self.gaps)
        self._had_baseline = self._had_baseline or ph.name == "baseline"
        s = summarise_phase(windows, ph.t0, t1, self.normaliser, baseline=ph.name == "baseline",
                            had_baseline=self._had_baseline, hop_s=self.proc.hop_s, min_quality=self.proc.min_quality,
                            lost_s=lost_s, unavailable=self.unavailable_reason if self.inlet is None else None)
        result = PhaseEngagement(s.engagement, s.index, round(s.quality, 4), s.reason, series=s.smoothed,
                                 lost_s=round(lost_s, 3))
        rows = [[ph.turn if ph.turn is not None else "", ph.name, repr(w.t_end), fmt(w.index_raw),
                 fmt(w.index_smoothed), fmt(float(n)), f"{w.clean_fraction:.3f}", w.reason]
                for w, n in zip(windows, s.normalised)]
        return result, (rows, lost_s)

    def _write_phase(self, ph: _Phase, t1: float, result: PhaseEngagement, rows_lost) -> None:
        rows, lost_s = rows_lost
        self.files.write("windows.csv", WINDOWS_HEADER, rows)
        self.files.write("phases.csv", PHASES_HEADER, [[
            ph.turn if ph.turn is not None else "", ph.name, repr(ph.t0), repr(t1), fmt(result.engagement),
            fmt(result.index), f"{result.quality:.3f}", len(rows), f"{lost_s:.3f}", result.reason,
            "" if ph.last_sample is None else repr(ph.last_sample), repr(self._started)]])

    def close(self) -> None:
        """Stop the reader, record an open gap, close the inlet, the marker outlet, the simulator, files."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(3.0)
        self._stop_xdf()
        if self.gaps and self.gaps[-1].end is None:
            g = self.gaps[-1]
            self.files.write("gaps.csv", GAPS_HEADER, [[f"{g.start:.6f}", "", "", f"{g.kind} (until the end)"]])
        self._event("eeg_monitor_closed", f"{self.samples_received} samples, {len(self.gaps)} gaps")
        self._resolver = None
        if self.inlet is not None:
            if self.proc.record_raw:
                self._record_raw(np.empty((0, len(self.inlet.scalp_index))), np.empty(0), force=True)
            self.inlet.close()
        if self.markers is not None:
            self.markers.close()
        if self.simulator is not None:
            self.simulator.stop()
        self.files.close()

    def __enter__(self) -> "LslMonitor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

