"""Opening the session's engagement monitor: find (or simulate) the EEG stream, then start the monitor.

``open_monitor(mode, eeg, session_dir, rng)`` is what the session calls. It returns an
``EngagementMonitor`` (see ``nao_trainer.ports``):

* ``"lsl"``: the live headband of the study's ``eeg.device`` (``eeg/device.py``): a Muse via muselsl is
  resolved by the study's query, a device that makes its stream in this process (BrainFlow) starts it;
* ``"simulated"``: the device's simulation, e.g. a
  :class:`~nao_trainer.eeg.simulated_muse.SimulatedMuse` in this process, monitored over a real LSL
  stream; ``set_target`` drives its engagement;
* ``"off"``: ``ports.NullMonitor``.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from nao_trainer.eeg.inlet import EEGInlet, StreamQuery, resolve_eeg
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.markers import MarkerOutlet, marker_source_id
from nao_trainer.eeg.monitor import LslMonitor
from nao_trainer.eeg.settings import EEGSettings, simulated_refusal
from nao_trainer.errors import EEGUnavailable
from nao_trainer.ports import EngagementMonitor, NullMonitor

log = logging.getLogger(__name__)


def _no_stream_message(query: StreamQuery, settings: EEGSettings) -> str:
    what = (f"no EEG stream ({query.describe()}) found by LSL in scope {settings.lsl_scope!r} within "
            f"{settings.processing.resolve_timeout_s:g} s (eeg.stream_type / eeg.stream_name / eeg.source_id in the study config, or --eeg-source-id)")
    hint = settings.eeg_device().start_hint
    if settings.required:
        return f"{what}; {hint} and try again, or run with --eeg off"
    return f"{what}; continuing without EEG - {hint} and the session uses it from then on"


def open_monitor(mode: str, eeg_cfg: EEGSettings | Mapping[str, Any] | None, session_dir: Path | None,
                 rng: np.random.Generator, pseudonym: str | None = None, record_xdf: bool = False,
                 rest_target: float = 0.5, person: bool = False) -> EngagementMonitor:
    """The session's engagement monitor for ``mode`` "lsl", "simulated" or "off".

    ``eeg_cfg`` is the study's ``eeg`` section: the typed settings the config validated at load, or a
    mapping (validated here: a wrong key raises ``ConfigError`` naming it). "lsl" without a stream: ``EEGUnavailable`` when ``required``, otherwise a monitor
    whose phases say "EEG unavailable" and that attaches if a stream appears later.
    "simulated" starts a simulated Muse (seeded from ``rng``) that ``set_target`` drives; it shows
    ``rest_target`` until then (the simulated participant's resting engagement, for the baseline phase).
    ``record_xdf``: also record ``<session_dir>/session.xdf`` (``eeg.xdf`` can turn it off), started
    before this returns, so the session's first marker is in the file.
    ``person``: a person answers or a real robot plays; a simulated or replayed LSL stream is then
    refused (``EEGUnavailable``, exit 4) unless ``eeg.allow_simulated`` (see ``settings.simulated_refusal``).
    """
    if isinstance(eeg_cfg, EEGSettings):  # validated once, at load
        settings = eeg_cfg if eeg_cfg.mode == mode else dataclasses.replace(eeg_cfg, mode=mode)
    else:
        settings = EEGSettings.from_mapping(eeg_cfg, mode)
    if settings.mode == "off":
        return NullMonitor()
    configure_lsl(settings.lsl_scope)
    device = settings.eeg_device()
    # The device starts what makes its stream in this process (a simulated Muse, a BrainFlow board
    # republished to LSL), pinned by source_id; a Muse via muselsl is found by the study's query.
    source = device.open(settings, rng, simulated=settings.mode == "simulated", rest_target=rest_target)
    simulator, query = source.producer, source.query
    markers = None
    try:
        timeout = settings.processing.resolve_timeout_s if simulator is None else max(5.0, settings.processing.resolve_timeout_s)
        info = resolve_eeg(query, timeout, settings.lsl_scope)
        if info is None and (settings.required or simulator is not None):
            raise EEGUnavailable(_no_stream_message(query, settings))
        inlet, reason = None, _no_stream_message(query, settings)
        if info is not None:
            try:
                inlet, reason = EEGInlet.open(info, settings.lsl_scope, montage=source.montage), ""
            except Exception as exc:  # irregular rate, vanished between resolve and open, ...
                reason = str(exc) if isinstance(exc, EEGUnavailable) else (
                    f"EEG stream {info.name()!r} (source_id {info.source_id()!r}) was found but could not be "
                    f"opened ({type(exc).__name__}: {exc}); check the headband bridge and try again")
                if settings.required or simulator is not None:
                    raise EEGUnavailable(reason) from None
        refusal = simulated_refusal(inlet.identity(), settings) if inlet is not None and person else ""
        if refusal:  # a made-up signal recorded as a person's: refused whether or not EEG is required
            inlet.close()
            raise EEGUnavailable(refusal)
        if inlet is None:
            log.warning("EEG unavailable: %s", reason)
        folder = Path(session_dir).name if session_dir else None
        markers = MarkerOutlet(marker_source_id(pseudonym, folder), scope=settings.lsl_scope)
        monitor = LslMonitor(settings, query, session_dir, inlet, markers, reason, simulator, record_xdf,
                             refuse_simulated=person, montage=source.montage)
        if simulator is not None:  # a simulated headband is "put on" before the greeting: fill one window
            monitor.wait_for_windows(1, settings.processing.window_s + 2.0)
        return monitor
    except BaseException:
        if simulator is not None:
            simulator.stop()
        if markers is not None:
            markers.close()
        raise
