"""Per-turn engagement of recorded sessions of the published layout (``nao-trainer engagement``).

Two definitions:

``compat="authors2018"``
    Reproduces the authors' tables ``derived/index_1.csv`` and ``derived/normalized_1.csv`` (dataset
    README): band lines of each turn's listening recording ``robot_N``; relative alpha, beta, theta
    averaged over the 4 channels per 10 Hz sample; the lagged EWMA restarted per turn; per-sample
    ``E = S_beta / (S_alpha + S_theta)``; ``engagement_index`` = the turn's mean E; ``engagement`` = the
    turn's mean of E min-max scaled over all samples of the session.

``compat=None`` (the project's definitions, ``docs/explanation/engagement.md``)
    *bands source*: per 10 Hz sample, theta/alpha/beta averaged over the channels whose headband
    contact ``h`` is good or ok (1 or 2), at least ``min_channels`` of them, ``E = beta / (alpha + theta)``,
    the correct EWMA ``s_t = a s_(t-1) + (1-a) E_t`` restarted per turn over the usable samples.
    *raw source* (recordings with only raw ``eeg`` lines, or ``source="raw"``): the online estimator
    (:class:`nao_trainer.core.engagement.OnlineEngagement`) on the raw EEG at ``fs`` Hz, samples stamped
    ``i / fs``, with the live monitor's processing defaults (``core.eeg.Processing``: EWMA a = 0.75 per
    0.25 s window). ``engagement_index`` = mean raw E of the usable samples/windows, ``engagement`` = mean of
    their smoothed E normalised per participant (:class:`EngagementNormaliser`): baseline = the
    ``intro`` recording (greeting and instructions) as reference when present, then running bounds over the
    task phases turn by turn; without ``intro`` the baseline is all listening-phase values of the session.
    A turn below ``min_quality`` usable signal is empty, with the reason.

A missing, malformed or truncated recording empties only its turn (the reason names file and line).
"""
from __future__ import annotations

import json
import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from nao_trainer.core import engagement as core
from nao_trainer.core import phase
from nao_trainer.core.eeg import CHANNELS, RAW_RATE_HZ, Processing
from nao_trainer.data.published import Recording, find_sessions, read_recording, read_state_eeg, session_id
from nao_trainer.errors import DataError

COMPAT_MODES: tuple[str, ...] = ("authors2018",)
SOURCES: tuple[str, ...] = ("bands", "raw")
BAND_RATE_HZ = 10.0  # the Muse's band-power messages
GOOD_CONTACT = (1.0, 2.0)  # h: 1 good, 2 ok, 4 bad
COLUMNS: tuple[str, ...] = ("turn", "engagement_index", "engagement", "quality", "contact", "reason")
ANSWER_COLUMNS: tuple[str, ...] = ("answer_index", "answer_engagement", "answer_quality", "answer_reason")


#: The live monitor's processing defaults (``eeg.processing``): the raw source re-analyses a recording
#: exactly as a live session would have.
_LIVE = Processing()


@dataclass(frozen=True)
class OfflineSettings:
    """Knobs of the project's own offline definition (ignored by ``compat="authors2018"``).

    The raw-EEG defaults are the live monitor's (:class:`nao_trainer.core.eeg.Processing`).
    """

    a: float = 0.9  # EWMA factor per 10 Hz band sample (time constant 0.1 s / (1 - a) = 1 s)
    raw_a: float = _LIVE.ewma_a  # EWMA factor per raw-EEG window (one every hop_s): 0.75, also 1 s
    min_channels: int = _LIVE.min_clean_channels  # good-contact (bands) / clean (raw) channels per sample/window
    min_quality: float = _LIVE.min_quality  # fraction of usable samples/windows a turn needs
    fs: float = RAW_RATE_HZ  # raw EEG sampling rate
    window_s: float = _LIVE.window_s
    hop_s: float = _LIVE.hop_s
    thresholds: core.QualityThresholds = core.QualityThresholds()


@dataclass(frozen=True)
class TurnSeries:
    """Per-sample (bands) or per-window (raw) values of one turn, for plots. ``t`` in s from its start."""

    t: np.ndarray
    index: np.ndarray  # raw E (NaN where unusable)
    smoothed: np.ndarray
    normalised: np.ndarray


@dataclass(frozen=True)
class TurnEngagement:
    """One turn's listening-phase engagement; ``None`` values come with a ``reason``."""

    turn: int
    engagement_index: float | None
    engagement: float | None
    quality: float  # fraction of usable samples (bands) / clean windows (raw), 0..1
    contact: float | None  # fraction of h samples with all 4 scalp channels good/ok
    reason: str = ""
    # the answer phase (user_N), only when asked for (``answer=True``)
    answer_index: float | None = None
    answer_engagement: float | None = None
    answer_quality: float | None = None
    answer_reason: str = ""

    def as_dict(self, answer: bool = False) -> dict:
        cols = COLUMNS + (ANSWER_COLUMNS if answer else ())
        out = {c: getattr(self, c) for c in cols}
        return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in out.items()}


@dataclass
class SessionEngagement:
    """The per-turn engagement of one session, how it was computed, and the series behind it."""

    session: str
    path: Path
    compat: str | None
    source: str  # "bands" or "raw"
    baseline: str  # what the normalisation was based on
    turns: list[TurnEngagement]
    series: dict[int, TurnSeries] = field(default_factory=dict, repr=False)
    answer: bool = False  # whether the answer-phase columns were computed

    def as_dict(self) -> dict:
        return {
            "session": self.session,
            "compat": self.compat,
            "source": self.source,
            "baseline": self.baseline,
            "turns": [t.as_dict(self.answer) for t in self.turns],
        }


# ----------------------------------------------------------------------------------------------
# Locating a turn's recording
# ----------------------------------------------------------------------------------------------


def _band_file(session_dir: Path, name: str) -> Path | None:
    """The band lines of recording ``name``: ``EEG/bands_<name>``, else the raw file ``<name>``."""
    for p in (session_dir / "EEG" / f"bands_{name}", session_dir / name):
        if p.is_file():
            return p
    return None


def _choose_source(session_dir: Path, first_recording: str, requested: str | None) -> str:
    if requested is not None:
        return requested
    if (session_dir / "EEG" / f"bands_{first_recording}").is_file():
        return "bands"
    raw = session_dir / first_recording
    if raw.is_file():
        try:
            rec = read_recording(raw, prefixes=("a", "b", "t"))
        except DataError:
            return "bands"  # the turn will report the error itself
        return "bands" if all(p in rec for p in ("a", "b", "t")) else "raw"
    return "bands"


# ----------------------------------------------------------------------------------------------
# One recording -> per-sample (bands) or per-window (raw) values
# ----------------------------------------------------------------------------------------------


@dataclass
class _Phase:
    """The values of one recording (a turn's listening or answer phase), or why there are none."""

    t: np.ndarray | None = None
    raw: np.ndarray | None = None  # E per sample/window, NaN where unusable
    smoothed: np.ndarray | None = None
    quality: float = 0.0
    contact: float | None = None
    reason: str = ""

    @property
    def usable(self) -> bool:
        return self.smoothed is not None and not self.reason


def _contact(rec: Recording) -> float | None:
    h = rec.data.get("h")
    if h is None or len(h) == 0:
        return None
    return float(np.isin(h, GOOD_CONTACT).all(axis=1).mean())


def _authors_turn(rec: Recording) -> np.ndarray:
    """Per-sample E of one turn as the authors computed it (lagged EWMA on channel-averaged bands)."""
    bands = rec.bands(("a", "b", "t")).mean(axis=2)  # (n, 3): alpha, beta, theta averaged over channels
    s = core.lagged_ewma_authors2018(bands, 0.9)
    return core.engagement_index(s[:, 2], s[:, 0], s[:, 1])


def _own_bands_turn(rec: Recording, settings: OfflineSettings) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample raw and smoothed E from band lines, channels restricted to good contact."""
    bands = rec.bands(("t", "a", "b"))  # (n, 3, 4)
    n = bands.shape[0]
    good = np.isfinite(bands).all(axis=1)
    h = rec.data.get("h")
    if h is not None and len(h):
        m = min(n, len(h))
        contact = np.zeros((n, bands.shape[2]), dtype=bool)
        contact[:m] = np.isin(h[:m], GOOD_CONTACT)
        good &= contact
    k = good.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(good[:, None, :], bands, 0.0).sum(axis=2) / k[:, None]
    e = core.engagement_index(mean[:, 0], mean[:, 1], mean[:, 2])
    e[k < settings.min_channels] = np.nan
    smoothed = np.full(n, np.nan)
    ok = np.isfinite(e)
    if ok.any():
        smoothed[ok] = core.ewma(e[ok], settings.a)
    return e, smoothed


def _from_bands(rec: Recording, compat: str | None, settings: OfflineSettings) -> _Phase:
    if not all(p in rec for p in ("a", "b", "t")):
        raise DataError(f"{rec.path}: no band lines (a, b, t); use --source raw for raw EEG")
    if compat:
        raw = smoothed = _authors_turn(rec)
    else:
        raw, smoothed = _own_bands_turn(rec, settings)
    ph = _Phase(np.arange(len(raw)) / BAND_RATE_HZ, raw, smoothed, contact=_contact(rec))
    ph.quality = float(np.isfinite(smoothed).mean()) if len(raw) else 0.0
    if not len(raw):
        ph.reason = f"{rec.path}: no band samples"
    elif not compat and ph.quality < settings.min_quality:
        ph.reason = (
            f"only {ph.quality:.0%} of samples with >= {settings.min_channels} channels in good "
            f"contact (needs {settings.min_quality:.0%})"
        )
    return ph


def _from_raw(rec: Recording, settings: OfflineSettings) -> _Phase:
    """The online estimator over a recording's raw EEG, samples stamped ``i / fs``."""
    if "eeg" not in rec:
        raise DataError(f"{rec.path}: no raw 'eeg' lines; use --source bands")
    eeg = rec["eeg"]
    n_ch = eeg.shape[1]
    names = CHANNELS[:n_ch] if n_ch <= len(CHANNELS) else None
    est = core.OnlineEngagement(
        settings.fs, n_ch, settings.window_s, settings.hop_s, settings.raw_a,
        settings.thresholds, min(settings.min_channels, n_ch), channel_names=names,
    )
    windows = est.push(eeg, np.arange(len(eeg)) / settings.fs)
    ph = _Phase(contact=_contact(rec))
    if not windows:
        ph.reason = f"{rec.path}: shorter than one {settings.window_s:g} s analysis window ({len(eeg)} samples)"
        return ph
    ph.t = np.array([w.t_end for w in windows])
    ph.raw = np.array([np.nan if w.index_raw is None else w.index_raw for w in windows])
    ph.smoothed = np.array([np.nan if w.index_smoothed is None else w.index_smoothed for w in windows])
    agg = phase.aggregate_phase(windows, ph.t[0] - settings.hop_s, ph.t[-1], settings.hop_s, None, settings.min_quality)
    ph.quality, ph.reason = agg.quality, agg.reason
    return ph


def _phase(session_dir: Path, name: str, src: str, compat: str | None, settings: OfflineSettings) -> _Phase:
    """Read and compute one recording; any DataError becomes the phase's reason."""
    path = _band_file(session_dir, name) if src == "bands" else session_dir / name
    if path is None or not path.is_file():
        return _Phase(reason=f"{session_dir / name}: recording not found")
    try:
        if src == "bands":
            return _from_bands(read_recording(path, prefixes=("a", "b", "t", "h")), compat, settings)
        return _from_raw(read_recording(path, prefixes=("eeg", "h")), settings)
    except DataError as exc:
        return _Phase(reason=str(exc))


# ----------------------------------------------------------------------------------------------
# Sessions
# ----------------------------------------------------------------------------------------------


def _mean(v: np.ndarray) -> float | None:
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def session_engagement(session_dir: Path, compat: str | None = None, source: str | None = None,
                       settings: OfflineSettings = OfflineSettings(), answer: bool = False) -> SessionEngagement:
    """Per-turn listening-phase engagement of one session folder of the published layout.

    ``compat``: None (the project's definitions) or ``"authors2018"`` (the published tables).
    ``source``: ``"bands"`` (Muse band lines: ``EEG/bands_robot_N``, else the raw ``robot_N``), ``"raw"``
    (band powers computed from raw ``eeg`` lines), or None to use band lines when the session has them.
    ``answer``: also compute the answer phase (``user_N``) with the project's definitions.
    Raises DataError when the session itself cannot be read (``state_EEG``); a bad recording only
    empties its turn.
    """
    check_options(compat, source, answer)
    return _session_engagement(Path(session_dir), compat, source, settings, answer)


def check_options(compat: str | None, source: str | None, answer: bool) -> None:
    """DataError when ``compat``, ``source`` and ``answer`` do not go together (checked once per call)."""
    if compat is not None and compat not in COMPAT_MODES:
        raise DataError(f"unknown compat mode {compat!r} (known: {', '.join(COMPAT_MODES)})")
    if source is not None and source not in SOURCES:
        raise DataError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    if compat and source == "raw":
        raise DataError("--compat authors2018 uses the Muse band lines; drop --source raw")
    if compat and answer:
        raise DataError("--answer uses the project's definitions; the authors' tables have no answer phase; "
                        "drop --answer or --compat")


def _session_engagement(
    session_dir: Path, compat: str | None, source: str | None, settings: OfflineSettings, answer: bool
) -> SessionEngagement:
    """:func:`session_engagement` with options already checked."""
    if not (session_dir / "state_EEG").is_file():
        raise DataError(f"{session_dir}: no state_EEG file (not a session of the published layout?)")
    states = read_state_eeg(session_dir / "state_EEG")
    if not states:
        raise DataError(f"{session_dir / 'state_EEG'}: no turns")
    src = "bands" if compat else _choose_source(session_dir, states[0].robot_file, source)
    if src == "raw" and not any((session_dir / st.robot_file).is_file() for st in states):
        hint = "; this session has only EEG/bands_* files: use --source bands" if (session_dir / "EEG").is_dir() else ""
        raise DataError(f"{session_dir}: no raw recordings (robot_N) for --source raw{hint}")
    listening = [_phase(session_dir, st.robot_file, src, compat, settings) for st in states]
    answers = [_phase(session_dir, st.user_file, src, None, settings) for st in states] if answer else None
    if compat:
        baseline, norm = _normalise_authors(listening)
        norm_answer = None
    else:
        baseline, norm, norm_answer = _normalise_own(session_dir, listening, answers, src, settings)
    out: list[TurnEngagement] = []
    series: dict[int, TurnSeries] = {}
    for i, (ph, nv) in enumerate(zip(listening, norm)):
        turn = i + 1
        extra: dict = {}
        if answers is not None:
            a, an = answers[i], norm_answer[i]
            ok = a.usable and an is not None
            extra = dict(
                answer_index=_mean(a.raw[np.isfinite(a.smoothed)]) if a.usable else None,
                answer_engagement=_mean(an[np.isfinite(a.smoothed)]) if ok else None,
                answer_quality=a.quality,
                answer_reason=a.reason if not a.usable else ("" if ok else "no normalisation scale"),
            )
        if not ph.usable:
            out.append(TurnEngagement(turn, None, None, ph.quality, ph.contact, ph.reason or "no data", **extra))
            continue
        ok = np.isfinite(ph.smoothed)
        index = _mean(ph.smoothed if compat else ph.raw[ok])
        eng = _mean(nv[ok]) if nv is not None else None
        reason = "" if eng is not None else "no normalisation scale (too few usable values in the session)"
        out.append(TurnEngagement(turn, index, eng, ph.quality, ph.contact, reason, **extra))
        series[turn] = TurnSeries(ph.t, ph.raw, ph.smoothed, nv if nv is not None else np.full(len(ph.raw), np.nan))
    return SessionEngagement(session_id(session_dir), session_dir, compat, src, baseline, out, series, answer)


def _normalise_authors(phases: list[_Phase]) -> tuple[str, list[np.ndarray | None]]:
    """Min-max over all samples of the session's usable turns (the authors' normalized_1.csv)."""
    label = "session min-max (authors2018)"
    values = [p.smoothed for p in phases if p.usable]
    if not values:
        return label, [None] * len(phases)
    scaled = phase.minmax_scale(np.concatenate(values))
    if np.isnan(scaled).all():  # a flat session: no scale
        return label, [None] * len(phases)
    parts = iter(np.split(scaled, np.cumsum([len(v) for v in values])[:-1]))
    return label, [next(parts) if p.usable else None for p in phases]


def _baseline_values(session_dir: Path, src: str, settings: OfflineSettings) -> np.ndarray | None:
    """Smoothed E of the ``intro`` recording (greeting and instructions), None when there is none."""
    if not (session_dir / "intro").is_file():
        return None
    ph = _phase(session_dir, "intro", src if src == "raw" else "bands", None, settings)
    if ph.smoothed is None:
        if ph.reason and "recording not found" not in ph.reason:
            raise DataError(ph.reason)
        return None
    return ph.smoothed


def _normalise_own(session_dir: Path, listening: list[_Phase], answers: list[_Phase] | None, src: str,
                   settings: OfflineSettings) -> tuple[str, list[np.ndarray | None], list[np.ndarray | None] | None]:
    """The project's rule: intro baseline plus running bounds in recording order; else the session itself."""
    normaliser = phase.EngagementNormaliser()
    why = ""
    try:
        base = _baseline_values(session_dir, src, settings)
    except DataError as exc:
        base, why = None, f" (intro unusable: {exc})"
    n = len(listening)
    norm: list[np.ndarray | None] = [None] * n
    norm_answer: list[np.ndarray | None] | None = None if answers is None else [None] * n
    if base is not None and np.isfinite(base).sum() >= normaliser.min_values:
        normaliser.fit_baseline(base)
        for i in range(n):  # listening then answer, turn by turn: what a live session would compute
            if listening[i].usable:
                norm[i] = normaliser.extend(listening[i].smoothed)
            if answers is not None and answers[i].usable:
                norm_answer[i] = normaliser.extend(answers[i].smoothed)  # type: ignore[index]
        return "intro + running bounds", norm, norm_answer
    usable = [p.smoothed for p in listening if p.usable]
    normaliser.fit_baseline(np.concatenate(usable) if usable else [])
    norm = [normaliser.normalise(p.smoothed) if p.usable else None for p in listening]
    if answers is not None:
        norm_answer = [normaliser.normalise(p.smoothed) if p.usable else None for p in answers]
    return "session listening phases" + (why or " (no intro recording)"), norm, norm_answer


@dataclass(frozen=True)
class EngagementFailure:
    """A session that could not be computed at all (its ``state_EEG`` is missing or malformed)."""

    session: str
    message: str


def _one(args: tuple) -> "SessionEngagement | EngagementFailure":
    path, compat, source, settings, answer, skip = args
    try:
        return _session_engagement(path, compat, source, settings, answer)
    except DataError as exc:
        if not skip:
            raise
        return EngagementFailure(session_id(path), str(exc))


def session_engagement_many(root: Path, compat: str | None = None, source: str | None = None,
                            settings: OfflineSettings = OfflineSettings(), workers: int = 2,
                            progress: Callable[[int, int, str], None] | None = None, answer: bool = False,
                            problems: list[EngagementFailure] | None = None) -> list[SessionEngagement]:
    """:func:`session_engagement` for every session under ``root``, in natural order.

    ``workers > 1`` spreads sessions over processes. ``progress(done, total, session_id)`` is called after
    each session (the CLI prints it to stderr). A session that cannot be read raises DataError, unless
    a ``problems`` list is given: it is then appended there and skipped.
    """
    check_options(compat, source, answer)
    sessions = find_sessions(Path(root))
    skip = problems is not None
    jobs = [(p, compat, source, settings, answer, skip) for p in sessions]
    done: list[SessionEngagement | EngagementFailure] = []
    if workers <= 1 or len(jobs) <= 1:
        for k, job in enumerate(jobs, 1):
            done.append(_one(job))
            if progress:
                progress(k, len(jobs), done[-1].session)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for k, res in enumerate(pool.map(_one, jobs, chunksize=max(1, len(jobs) // (4 * workers))), 1):
                done.append(res)
                if progress:
                    progress(k, len(jobs), res.session)
    if problems is not None:
        problems.extend(r for r in done if isinstance(r, EngagementFailure))
    return [r for r in done if isinstance(r, SessionEngagement)]


# ----------------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------------


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    text = str(v)
    if any(c in text for c in ',"\n'):
        text = '"' + text.replace('"', '""') + '"'
    return text


def to_csv(results: Sequence[SessionEngagement], with_session: bool | None = None) -> str:
    """One line per turn; a leading ``session`` column when there are several sessions."""
    with_session = len(results) > 1 if with_session is None else with_session
    answer = any(r.answer for r in results)
    cols = (("session",) if with_session else ()) + COLUMNS + (ANSWER_COLUMNS if answer else ())
    lines = [",".join(cols)]
    for r in results:
        for t in r.turns:
            d = t.as_dict(answer)
            d["session"] = r.session
            lines.append(",".join(_cell(d[c]) for c in cols))
    return "\n".join(lines) + "\n"


def to_json(results: Sequence[SessionEngagement], as_list: bool | None = None) -> str:
    """The sessions as JSON (one object for a single session, else a list); None -> null."""
    data = [r.as_dict() for r in results]
    as_list = len(data) != 1 if as_list is None else as_list
    return json.dumps(data if as_list else data[0], indent=2, allow_nan=False) + "\n"
