"""The ``eeg`` section of a study config, declared once: each field carries its rule (``core.settings``).

``EEGSettings`` is its own schema: the config loader validates the section with the same validator
and message style as every other section (``key 'eeg.mode' must be one of ...``, with file:line);
``EEGSettings.from_mapping(data, mode, where=...)`` is the same check for callers with a plain mapping
(the monitor's factory). The modes and LSL scopes are listed once, here and in ``eeg.lsl_scope``.
Light on purpose: no numpy, no pylsl (``--help`` stays fast).
"""
from __future__ import annotations

from dataclasses import field
from typing import Any, Callable, Mapping

from nao_trainer.core.eeg import Processing
from nao_trainer.core.settings import SettingError, build, setting, settings
from nao_trainer import registry
from nao_trainer.eeg.lsl_scope import SCOPES
from nao_trainer.errors import ConfigError

MODES = ("off", "simulated", "lsl")

#: Maps a dotted key (``eeg.mode``, ``eeg.processing.window_s``) to where its value came from.
Where = Callable[[str], Any]


def _stream_property(value: str) -> str | None:
    if not value.strip():
        return f"must be a non-empty text, got {value!r}"
    # The EEG inlet resolves streams with an XPath predicate in single quotes (eeg/inlet.py refuses a quote).
    if "'" in value:
        return f"must not contain a quote ('): LSL stream properties are matched inside quotes; remove it (got {value!r})"
    return None


def _registered_device(value: str) -> str | None:
    try:
        registry.spec("eeg_device", value)
    except ConfigError as exc:
        return str(exc)
    return None


@settings
class EEGSettings:
    """The ``eeg`` section of a study config, validated."""

    mode: str = setting("off", kind=str, choices=MODES,
                        doc="off | simulated (the device's simulation) | lsl (the live headband, read over LSL)")
    device: str = setting(registry.default("eeg_device"), kind=str, check=_registered_device,
                          doc="the EEG device plug-in (nao-trainer plugins lists them): muse, brainflow, ...")
    device_settings: dict = setting(factory=dict, kind=dict, free=True,
                                    doc="the device's own settings (its Settings class; nao-trainer plugins)")
    required: bool = setting(False, kind=bool, doc="refuse to start (exit 4) without a usable stream")
    stream_type: str = setting("EEG", kind=str, check=_stream_property, doc="LSL stream type to resolve")
    stream_name: str | None = setting(None, kind=str, nullable=True, check=_stream_property, doc="LSL stream name")
    source_id: str | None = setting(None, kind=str, nullable=True, check=_stream_property, doc="LSL source_id")
    lsl_scope: str = setting("machine", kind=str, choices=SCOPES, doc="LSL discovery scope")
    processing: Processing = field(default_factory=Processing)
    xdf: bool = setting(True, kind=bool, doc="also record session.xdf (eeg/xdf.py)")
    missing_alert_turns: int = setting(3, kind=int, min=0, max=1000,
                                       doc="tell the operator after this many turns in a row without EEG (0 = never)")
    turn_requires_eeg: bool = setting(False, kind=bool,
                                      doc="a turn whose listening phase lost EEG is played again (once), as after "
                                          "a lost robot link, once the stream is back (docs/how-to/headbands.md)")
    reconnect_wait_s: float = setting(30.0, kind=(int, float), min=0.0, max=600.0,
                                      doc="with turn_requires_eeg: how long a turn waits for a lost stream to return, s")
    allow_simulated: bool = setting(False, kind=bool,
                                    doc="pilots only: let a session where a person answers or a real robot plays "
                                        "take a simulated or replayed stream (simulate-muse); --allow-simulated-eeg")

    def __post_init__(self) -> None:
        # the device's own settings, validated with the section (``key 'eeg.device_settings.board' ...``)
        from nao_trainer.eeg.device import make_device

        device = make_device(self.device, self.device_settings, prefix="device_settings")
        object.__setattr__(self, "_device", device)

    def eeg_device(self):
        """The device plug-in (``eeg.device.EEGDevice``) with its validated settings."""
        return self._device  # type: ignore[attr-defined]

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None, mode: str | None = None,
                     where: Where | None = None) -> "EEGSettings":
        """Validate the ``eeg`` section (``mode``, when given, overrides ``data["mode"]``).

        Raises ``ConfigError``: ``[<where>: ]key 'eeg.<key>' <problem>`` (``core.settings``'s one style).
        """
        data = dict(data or {})
        if mode is not None:
            data["mode"] = mode
        try:
            return build(cls, data, "eeg")
        except SettingError as exc:
            if where is None:
                raise
            raise ConfigError(f"{where(exc.key)}: {exc}") from None


def simulated_refusal(identity: Mapping[str, Any], settings: EEGSettings) -> str:
    """Why a session where a person answers (or a real robot plays) must not take this stream, or "".

    ``identity`` is ``EEGInlet.identity()``; a simulated or replayed stream would record made-up or
    someone else's engagement as the participant's, unless the study allows it for a pilot.
    """
    if not identity.get("simulated") or settings.allow_simulated:
        return ""
    return (f"EEG stream {identity.get('name')!r} (source_id {identity.get('source_id')!r}) is "
            f"{identity.get('acquisition')} (nao-trainer simulate-muse, or BrainFlow's synthetic board), not a headband, but a person answers or a "
            "real robot plays: its engagement would be recorded as theirs; start the headband bridge and pin it with "
            "eeg.source_id (--eeg-source-id), or for a pilot set eeg.allow_simulated: true (--allow-simulated-eeg)")


def ambiguous_streams(query: str, pinned: str | None, streams: list[tuple[str, str]]) -> str:
    """Why the choice among ``streams`` (name, source_id) is ambiguous, or "": several match ``query``
    and no source_id pins one, so a session could take another person's headband or a simulator."""
    if pinned or len(streams) < 2:
        return ""
    listed = ", ".join(f"{name!r} source_id {sid!r}" for name, sid in streams)
    return f"{len(streams)} EEG streams match ({query}) and none is pinned: {listed}"
