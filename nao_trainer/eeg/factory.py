"""Opening the session's engagement monitor: find (or simulate) the EEG stream, then start the monitor.

``open_monitor(mode, eeg, session_dir, rng)`` is what the session calls. It returns an
``EngagementMonitor`` (see ``nao_trainer.ports``):

* ``"lsl"``: resolves a stream (a Muse via muselsl, or any EEG stream named in the study config);
* ``"simulated"``: starts a :class:`~nao_trainer.eeg.simulated_muse.SimulatedMuse` in this process and
  monitors it over a real LSL stream; ``set_target`` drives its engagement;
* ``"off"``: ``ports.NullMonitor``.
"""
from __future__ import annotations

import dataclasses
import itertools
import logging
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from nao_trainer.eeg.inlet import EEGInlet, StreamQuery, resolve_eeg
from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.eeg.markers import MarkerOutlet, marker_source_id
from nao_trainer.eeg.monitor import LslMonitor
from nao_trainer.eeg.settings import EEGSettings
from nao_trainer.eeg.simulated_muse import SimulatedMuse, fake_mac
from nao_trainer.errors import EEGUnavailable
from nao_trainer.ports import EngagementMonitor, NullMonitor

log = logging.getLogger(__name__)

_SIM_COUNTER = itertools.count(1)


def _no_stream_message(query: StreamQuery, settings: EEGSettings) -> str:
    what = (f"no EEG stream ({query.describe()}) found by LSL in scope {settings.lsl_scope!r} within "
            f"{settings.processing.resolve_timeout_s:g} s (eeg.stream_type / eeg.stream_name / eeg.source_id in the study config, or --eeg-source-id)")
    if settings.required:
        return (f"{what}; start the headband bridge (`muselsl stream --lsltime`) or `nao-trainer simulate-muse` "
                "and try again, or run with --eeg off")
    return (f"{what}; continuing without EEG - start the headband bridge (`muselsl stream --lsltime`) or "
            "`nao-trainer simulate-muse` and the session uses it from then on")


def open_monitor(mode: str, eeg_cfg: EEGSettings | Mapping[str, Any] | None, session_dir: Path | None,
                 rng: np.random.Generator, pseudonym: str | None = None, record_xdf: bool = False) -> EngagementMonitor:
    """The session's engagement monitor for ``mode`` "lsl", "simulated" or "off".

    ``eeg_cfg`` is the study's ``eeg`` section: the typed settings the config validated at load, or a
    mapping (validated here: a wrong key raises ``ConfigError`` naming it). "lsl" without a stream: ``EEGUnavailable`` when ``required``, otherwise a monitor
    whose phases say "EEG unavailable" and that attaches if a stream appears later.
    "simulated" starts a simulated Muse (seeded from ``rng``) that ``set_target`` drives.
    ``record_xdf``: also record ``<session_dir>/session.xdf`` (``eeg.xdf`` can turn it off), started
    before this returns, so the session's first marker is in the file.
    """
    if isinstance(eeg_cfg, EEGSettings):  # validated once, at load
        settings = eeg_cfg if eeg_cfg.mode == mode else dataclasses.replace(eeg_cfg, mode=mode)
    else:
        settings = EEGSettings.from_mapping(eeg_cfg, mode)
    if settings.mode == "off":
        return NullMonitor()
    configure_lsl(settings.lsl_scope)
    simulator = None
    query = StreamQuery(settings.stream_type, settings.stream_name, settings.source_id)
    if settings.mode == "simulated":
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
        monitor = LslMonitor(settings, query, session_dir, inlet, markers, reason, simulator, record_xdf)
        if simulator is not None:  # a simulated headband is "put on" before the greeting: fill one window
            monitor.wait_for_windows(1, settings.processing.window_s + 2.0)
        return monitor
    except BaseException:
        if simulator is not None:
            simulator.stop()
        if markers is not None:
            markers.close()
        raise
