"""The ``eeg`` section of a study config: validated once, here, for the config loader and the monitor.

``EEGSettings.from_mapping(data, mode, where=...)`` is the one validator of the section (the
modes and LSL scopes are listed once, here and in ``eeg.lsl_scope``). Errors are one line naming
the key; the config loader passes ``where`` (dotted key -> "file:line") so they also name the
place in the study file. Light on purpose: no numpy, no pylsl (``--help`` stays fast).
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Callable, Mapping

from nao_trainer.core.eeg import Processing
from nao_trainer.errors import ConfigError
from nao_trainer.eeg.lsl_scope import SCOPES

MODES = ("off", "simulated", "lsl")
TEXT_KEYS = ("stream_type", "stream_name", "source_id")

#: Maps a dotted key (``eeg.mode``, ``eeg.processing.window_s``) to where its value came from.
Where = Callable[[str], Any]


def _text_problem(value: Any) -> str | None:
    if not isinstance(value, str):
        return f"must be a text, got {value!r}"
    if not value.strip():
        return f"must be a non-empty text, got {value!r}"
    # The EEG inlet resolves streams with an XPath predicate in single quotes (eeg/inlet.py refuses a quote).
    if "'" in value:
        return f"must not contain a quote ('): LSL stream properties are matched inside quotes; remove it (got {value!r})"
    return None


@dataclass(frozen=True)
class EEGSettings:
    """The ``eeg`` section of a study config, validated."""

    mode: str = "simulated"
    required: bool = False
    stream_type: str = "EEG"
    stream_name: str | None = None
    source_id: str | None = None
    lsl_scope: str = "machine"
    processing: Processing = field(default_factory=Processing)
    xdf: bool = True  # also record session.xdf (EEG + markers) with LabRecorder's engine (eeg/xdf.py)
    #: A pilot may take a simulated or replayed stream (``simulate-muse``) for a session where a person
    #: answers or a real robot plays; otherwise such a session refuses it (exit 4). ``--allow-simulated-eeg``.
    allow_simulated: bool = False

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None, mode: str | None = None,
                     where: Where | None = None) -> "EEGSettings":
        """Validate the ``eeg`` section (``mode``, when given, overrides ``data["mode"]``).

        Raises ``ConfigError``: ``[<where>: ]key 'eeg.<key>' <problem>``, or for ``eeg.processing``
        ``[<where>: ]eeg.processing.<key>: <problem>``.
        """
        data = dict(data or {})

        def fail(dotted: str, message: str) -> ConfigError:
            return ConfigError(f"{where(dotted)}: {message}" if where is not None else message)

        known = [f.name for f in fields(cls)]
        for key in data:
            if key not in known:
                raise fail(f"eeg.{key}", f"eeg.{key}: unknown key; known keys are {', '.join(sorted(known))}")
        mode = mode or data.get("mode", "simulated")
        if mode not in MODES:
            raise fail("eeg.mode", f"key 'eeg.mode' must be one of {', '.join(MODES)}, got {mode!r}")
        required = data.get("required", False)
        if not isinstance(required, bool):
            raise fail("eeg.required", f"key 'eeg.required' must be true/false, got {required!r}")
        xdf = data.get("xdf", True)
        if not isinstance(xdf, bool):
            raise fail("eeg.xdf", f"key 'eeg.xdf' must be true/false, got {xdf!r}")
        allow_simulated = data.get("allow_simulated", False)
        if not isinstance(allow_simulated, bool):
            raise fail("eeg.allow_simulated", f"key 'eeg.allow_simulated' must be true/false, got {allow_simulated!r}")
        scope = data.get("lsl_scope", "machine")
        if scope not in SCOPES:
            raise fail("eeg.lsl_scope", f"key 'eeg.lsl_scope' must be one of {', '.join(SCOPES)}, got {scope!r}")
        for key in TEXT_KEYS:
            value = data.get(key)
            if value is None and key == "stream_type" and key in data:
                raise fail(f"eeg.{key}", f"key 'eeg.{key}' needs a value (a text), got nothing")
            problem = None if value is None else _text_problem(value)
            if problem:
                raise fail(f"eeg.{key}", f"key 'eeg.{key}' {problem}")
        processing = data.get("processing")
        if processing is not None and not isinstance(processing, Mapping):
            raise fail("eeg.processing", f"key 'eeg.processing' must be a mapping, got {processing!r}")
        try:
            proc = Processing.from_mapping(processing)
        except ConfigError as exc:
            if where is None:
                raise
            raise fail(str(exc).split(":", 1)[0], str(exc)) from None
        return cls(mode=mode, required=required, stream_type=data.get("stream_type") or "EEG",
                   stream_name=data.get("stream_name"), source_id=data.get("source_id"), lsl_scope=scope,
                   processing=proc, xdf=xdf, allow_simulated=allow_simulated)


def simulated_refusal(identity: Mapping[str, Any], settings: EEGSettings) -> str:
    """Why a session where a person answers (or a real robot plays) must not take this stream, or "".

    ``identity`` is ``EEGInlet.identity()``; a simulated or replayed stream would record made-up or
    someone else's engagement as the participant's, unless the study allows it for a pilot.
    """
    if not identity.get("simulated") or settings.allow_simulated:
        return ""
    return (f"EEG stream {identity.get('name')!r} (source_id {identity.get('source_id')!r}) is "
            f"{identity.get('acquisition')} (nao-trainer simulate-muse), not a headband, but a person answers or a "
            "real robot plays: its engagement would be recorded as theirs; start the headband bridge and pin it with "
            "eeg.source_id (--eeg-source-id), or for a pilot set eeg.allow_simulated: true (--allow-simulated-eeg)")


def ambiguous_streams(query: str, pinned: str | None, streams: list[tuple[str, str]]) -> str:
    """Why the choice among ``streams`` (name, source_id) is ambiguous, or "": several match ``query``
    and no source_id pins one, so a session could take another person's headband or a simulator."""
    if pinned or len(streams) < 2:
        return ""
    listed = ", ".join(f"{name!r} source_id {sid!r}" for name, sid in streams)
    return f"{len(streams)} EEG streams match ({query}) and none is pinned: {listed}"
