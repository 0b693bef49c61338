"""The live engagement monitor: an EEG stream over LSL turned into per-phase engagement for a session.

``open_monitor(mode, eeg_cfg, session_dir, rng)`` is what the session calls. It returns an
``EngagementMonitor`` (see ``nao_trainer.ports``):

* ``"lsl"``: resolves a stream (a Muse via muselsl, or any EEG stream named in the study config);
* ``"simulated"``: starts a :class:`~nao_trainer.eeg.simulated_muse.SimulatedMuse` in this process and
  monitors it over a real LSL stream; ``set_target`` drives its engagement;
* ``"off"``: ``ports.NullMonitor``.

A background thread pulls chunks, feeds ``core.engagement.OnlineEngagement`` (sliding windows,
band powers, EWMA) and keeps the window results on the local LSL clock. Phases are delimited by
``local_clock()`` at ``begin_phase`` / ``end_phase``; ``end_phase`` aggregates the windows that end
inside the phase (``core.engagement.aggregate_phase``). Normalisation: an ``EngagementNormaliser``
fitted on the baseline phase (greeting and instructions), then updated with every phase's windows
(running bounds). Without a baseline the running bounds alone apply, so the first phases have no
normalised value until enough windows were seen (``engagement`` None, ``index`` still given).

Nothing is invented: a phase without enough clean signal returns ``engagement=None`` with the
reason. A stream that stops delivering for ``loss_timeout_s`` is marked lost (event, gap record);
the inlet reconnects by itself when a stream with the same source_id returns, and the gap is
closed. Files in ``<session>/eeg/``: ``stream.json``, ``events.csv``, ``windows.csv``,
``phases.csv``, ``gaps.csv`` and ``raw.csv`` (scalp samples with LSL stamps), all flushed as written.
"""
from __future__ import annotations

import itertools
import os
import logging
import threading
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from nao_trainer.core.engagement import OnlineEngagement, QualityThresholds, WindowResult
from nao_trainer.core.phase import EngagementNormaliser, summarise_phase
from nao_trainer.errors import EEGUnavailable
from nao_trainer.ports import EngagementMonitor, NullMonitor, PhaseEngagement
from nao_trainer.eeg.inlet import EEGInlet, StreamQuery, resolve_eeg
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.eeg.markers import MarkerOutlet, event_name, marker_source_id
from nao_trainer.eeg.session_files import (EVENTS_HEADER, GAPS_HEADER, PHASES_HEADER, WINDOWS_HEADER, SessionFiles,
                                          fmt)

log = logging.getLogger(__name__)

PHASES = ("baseline", "listening", "answer")
_SIM_COUNTER = itertools.count(1)


# ----------------------------------------------------------------------------------------------
# The monitor
# ----------------------------------------------------------------------------------------------


@dataclass
class _Phase:
    name: str
    turn: int | None
    t0: float


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
                 simulator=None) -> None:
        import pylsl

        self._clock = pylsl.local_clock
        self.settings = settings
        self.proc = settings.processing
        self.query = query
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
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._urgent = threading.Event()  # set while end_phase waits for samples in flight
        self._last_arrival = self._clock()
        self._last_stamp = -np.inf
        self._raw_pending: list[np.ndarray] = []
        self._raw_n = 0
        self._lost = False
        self._closed = False
        if inlet is not None:
            self._attach(inlet)
        self._thread = threading.Thread(target=self._run, name="eeg-monitor", daemon=True)
        self._thread.start()

    # -- state --------------------------------------------------------------------------------

    @property
    def records_eeg(self) -> bool:
        """Always: this monitor records EEG (``ports.EngagementMonitor``), even while the stream is away."""
        return True

    @property
    def available(self) -> bool:
        """True while a stream is attached and delivering."""
        return self.inlet is not None and not self._lost

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
        p = self.proc
        self.engine = OnlineEngagement(
            inlet.fs, len(inlet.scalp_index), window_s=p.window_s, hop_s=p.hop_s, a=p.ewma_a,
            thresholds=QualityThresholds(), min_clean_channels=min(p.min_clean_channels, len(inlet.scalp_index)),
            gap_factor=max(2.0, p.gap_tolerance_s * inlet.fs), channel_names=inlet.scalp_labels)
        self.unavailable_reason = ""
        self._last_arrival = self._clock()
        self.files.write_json("stream.json", {**inlet.describe(), "lsl_scope": self.settings.lsl_scope,
                                              "processing": asdict(self.proc)})
        self._event("eeg_stream_found", f"{inlet.name} {inlet.source_id} {inlet.fs:g} Hz "
                                        f"{'/'.join(inlet.scalp_labels)}")

    def _event(self, event: str, detail: str = "", turn: int | None = None, publish: bool = True) -> float:
        name = event_name(event, turn)
        stamp = self.markers.push(name) if (publish and self.markers is not None) else 0.0
        stamp = stamp or self._clock()
        self.files.write("events.csv", EVENTS_HEADER, [[f"{stamp:.6f}", name, detail]])
        return stamp

    # -- reader thread --------------------------------------------------------------------------

    def _run(self) -> None:
        import time as _time

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
                inlet = EEGInlet.open(info, self.settings.lsl_scope)
            except Exception as exc:  # not usable (e.g. irregular rate): say so once, keep looking
                self._rejected.add(info.source_id())
                self._event("eeg_stream_rejected", f"{info.name()} {info.source_id()}: {exc}", publish=False)
                return
            self._attach(inlet)
            self._resolver = None
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
        """Append scalp samples to ``eeg/raw.csv`` in blocks of about a second (never more unwritten)."""
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
        row = ",".join(["%.6f"] + ["%.3f"] * len(labels)) + "\n"
        with self.files.lock:
            fh = log_.raw_file()
            fh.write((row * len(block)) % tuple(block.ravel().tolist()))  # one format op: cheap
            fh.flush()

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
            self._cond.notify_all()
        log.warning("EEG stream %r lost (%s); waiting for it to return", self.inlet.name if self.inlet else "?", why)
        self._event("eeg_stream_lost", why)

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

    # -- EngagementMonitor ----------------------------------------------------------------------

    def mark(self, event: str, turn: int | None = None) -> None:
        """Publish a session event on the marker stream and log it to ``eeg/events.csv``."""
        self._event(event, "", turn)

    def set_target(self, engagement: float | None) -> None:
        """Drive the simulated Muse (simulated mode); ignored for a real headband or None."""
        if self.simulator is not None and engagement is not None:
            self.simulator.set_target(float(np.clip(engagement, 0.0, 1.0)))

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
            return [w for w in self.windows if t0 < w.t_end <= t1]

    def _summarise(self, ph: _Phase, t1: float, windows: list[WindowResult]):
        now = self._clock()
        lost_s = sum(g.overlap(ph.t0, t1, now) for g in self.gaps)
        self._had_baseline = self._had_baseline or ph.name == "baseline"
        s = summarise_phase(windows, ph.t0, t1, self.normaliser, baseline=ph.name == "baseline",
                            had_baseline=self._had_baseline, hop_s=self.proc.hop_s, min_quality=self.proc.min_quality,
                            lost_s=lost_s, unavailable=self.unavailable_reason if self.inlet is None else None)
        result = PhaseEngagement(s.engagement, s.index, round(s.quality, 4), s.reason, series=s.smoothed)
        rows = [[ph.turn if ph.turn is not None else "", ph.name, f"{w.t_end:.6f}", fmt(w.index_raw),
                 fmt(w.index_smoothed), fmt(float(n)), f"{w.clean_fraction:.3f}", w.reason]
                for w, n in zip(windows, s.normalised)]
        return result, (rows, lost_s)

    def _write_phase(self, ph: _Phase, t1: float, result: PhaseEngagement, rows_lost) -> None:
        rows, lost_s = rows_lost
        self.files.write("windows.csv", WINDOWS_HEADER, rows)
        self.files.write("phases.csv", PHASES_HEADER, [[
            ph.turn if ph.turn is not None else "", ph.name, f"{ph.t0:.6f}", f"{t1:.6f}", fmt(result.engagement),
            fmt(result.index), f"{result.quality:.3f}", len(rows), f"{lost_s:.3f}", result.reason]])

    def close(self) -> None:
        """Stop the reader, record an open gap, close the inlet, the marker outlet, the simulator, files."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(3.0)
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


# ----------------------------------------------------------------------------------------------
# Factory
# ----------------------------------------------------------------------------------------------


def _no_stream_message(query: StreamQuery, settings: EEGSettings) -> str:
    what = (f"no EEG stream ({query.describe()}) found by LSL in scope {settings.lsl_scope!r} within "
            f"{settings.processing.resolve_timeout_s:g} s (eeg.stream_type / eeg.stream_name in the study config)")
    if settings.required:
        return (f"{what}; start the headband bridge (`muselsl stream --lsltime`) or `nao-trainer simulate-muse` "
                "and try again, or run with --eeg off")
    return (f"{what}; continuing without EEG - start the headband bridge (`muselsl stream --lsltime`) or "
            "`nao-trainer simulate-muse` and the session uses it from then on")


def open_monitor(mode: str, eeg_cfg: Mapping[str, Any] | None, session_dir: Path | None,
                 rng: np.random.Generator, pseudonym: str | None = None) -> EngagementMonitor:
    """The session's engagement monitor for ``mode`` "lsl", "simulated" or "off".

    ``eeg_cfg`` is the study's ``eeg`` section (validated here: a wrong key raises ``ConfigError``
    naming it). "lsl" without a stream: ``EEGUnavailable`` when ``required``, otherwise a monitor
    whose phases say "EEG unavailable" and that attaches if a stream appears later.
    "simulated" starts a simulated Muse (seeded from ``rng``) that ``set_target`` drives.
    """
    settings = EEGSettings.from_mapping(eeg_cfg, mode)
    if settings.mode == "off":
        return NullMonitor()
    configure_lsl(settings.lsl_scope)
    simulator = None
    query = StreamQuery(settings.stream_type, settings.stream_name, settings.source_id)
    if settings.mode == "simulated":
        from nao_trainer.eeg.simulated_muse import SimulatedMuse, fake_mac

        # The simulator draws from its own generator (seeded from the session's) in its own thread,
        # so the session's random stream stays reproducible.
        sim_rng = np.random.default_rng(int(rng.integers(0, 2**63 - 1)))
        # pid + a counter keep source_ids unique across parallel processes and monitors (no cross-talk)
        source_id = f"Muse{fake_mac(sim_rng)}-sim{os.getpid()}-{next(_SIM_COUNTER)}"
        simulator = SimulatedMuse.start(sim_rng, target=0.5, source_id=source_id, scope=settings.lsl_scope)
        query = StreamQuery("EEG", None, source_id)
    markers = None
    try:
        timeout = settings.processing.resolve_timeout_s if simulator is None else max(5.0, settings.processing.resolve_timeout_s)
        info = resolve_eeg(query, timeout, settings.lsl_scope)
        if info is None and (settings.required or simulator is not None):
            raise EEGUnavailable(_no_stream_message(query, settings))
        inlet, reason = None, _no_stream_message(query, settings)
        if info is not None:
            try:
                inlet, reason = EEGInlet.open(info, settings.lsl_scope), ""
            except Exception as exc:  # irregular rate, vanished between resolve and open, ...
                reason = str(exc) if isinstance(exc, EEGUnavailable) else (
                    f"EEG stream {info.name()!r} (source_id {info.source_id()!r}) was found but could not be "
                    f"opened ({type(exc).__name__}: {exc}); check the headband bridge and try again")
                if settings.required or simulator is not None:
                    raise EEGUnavailable(reason) from None
        if inlet is None:
            log.warning("EEG unavailable: %s", reason)
        markers = MarkerOutlet(marker_source_id(pseudonym), scope=settings.lsl_scope)
        monitor = LslMonitor(settings, query, session_dir, inlet, markers, reason, simulator)
        if simulator is not None:  # a simulated headband is "put on" before the greeting: fill one window
            monitor.wait_for_windows(1, settings.processing.window_s + 2.0)
        return monitor
    except BaseException:
        if simulator is not None:
            simulator.stop()
        if markers is not None:
            markers.close()
        raise
