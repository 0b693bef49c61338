"""Engagement maths: band powers, the engagement index, smoothing, signal quality, analysis windows.

Pure: numpy only, no I/O, no clocks. The live monitor (``nao_trainer.eeg``) and the offline reader of
the published data (``nao_trainer.data.engagement``) both build on these functions, so a session and a
re-analysis compute engagement the same way.

Definitions (see ``docs/explanation/engagement.md``)
    * Bands: theta 4-8 Hz, alpha 8-13 Hz, beta 13-30 Hz, each as a fraction of the 1-40 Hz power
      (half-open intervals ``[lo, hi)`` on the frequency bins).
    * Engagement index (Pope et al. 1995; Tsiakas et al. 2018): ``E = beta / (alpha + theta)``.
    * Smoothing: the exponentially weighted moving average ``s_t = a * s_(t-1) + (1 - a) * y_t``.
    * Per-participant normalisation to [0, 1] and per-phase values: ``nao_trainer.core.phase``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

BANDS: dict[str, tuple[float, float]] = {"theta": (4.0, 8.0), "alpha": (8.0, 13.0), "beta": (13.0, 30.0)}
TOTAL_BAND: tuple[float, float] = (1.0, 40.0)
BAND_ORDER: tuple[str, ...] = ("theta", "alpha", "beta")

# ----------------------------------------------------------------------------------------------
# Band powers
# ----------------------------------------------------------------------------------------------


@lru_cache(maxsize=32)
def _welch_plan(nperseg: int, fs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hann taper, detrend projector and band-membership matrix for one segment length (cached)."""
    taper = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)  # periodic Hann (as scipy)
    t = np.arange(nperseg, dtype=float)
    design = np.stack([np.ones(nperseg), t - t.mean()], axis=1)  # constant + linear trend
    # residual = x - D (D^T D)^-1 D^T x; fold the taper in: tapered residual = R x with R below
    resid = np.eye(nperseg) - design @ np.linalg.pinv(design)
    proj = taper[:, None] * resid
    freqs = np.fft.rfftfreq(nperseg, 1.0 / fs)
    edges = [BANDS[name] for name in BAND_ORDER] + [TOTAL_BAND]
    member = np.stack([(freqs >= lo) & (freqs < hi) for lo, hi in edges], axis=1).astype(float)
    return proj, member, freqs


def welch_segment_length(n_samples: int, fs: float) -> int:
    """Segment length used by :func:`relative_band_powers`: 1 s of samples, or the window if shorter."""
    return int(min(n_samples, max(8, round(fs))))


def relative_band_powers(x: np.ndarray, fs: float) -> np.ndarray:
    """Relative theta, alpha, beta power of one window of raw EEG, per channel.

    ``x`` is ``(n_samples, n_channels)`` in microvolts with any DC offset (the Muse's raw values sit
    around 800-900 uV). Welch's method: segments of 1 s (1 Hz resolution; the whole window when it is
    shorter), 50 % overlap, each segment linearly detrended and Hann-tapered; the periodogram bins
    of each band are summed and divided by the 1-40 Hz sum. Returns ``(n_channels, 3)`` (theta,
    alpha, beta); each row sums to <= 1. A channel without 1-40 Hz power (above rounding noise) gives NaN.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"x must be (n_samples, n_channels), got shape {x.shape}")
    if fs <= 0:
        raise ValueError(f"fs must be > 0, got {fs}")
    n = x.shape[0]
    nperseg = welch_segment_length(n, fs)
    if n < 8:
        raise ValueError(f"a window needs at least 8 samples, got {n}")
    step = max(1, nperseg // 2)
    starts = np.arange(0, n - nperseg + 1, step)
    proj, member, _ = _welch_plan(nperseg, float(fs))
    segs = np.lib.stride_tricks.sliding_window_view(x, nperseg, axis=0)[starts]  # (nseg, ch, nperseg)
    tapered = segs @ proj.T  # detrend + taper per segment and channel
    power = np.abs(np.fft.rfft(tapered, axis=-1)) ** 2  # (nseg, ch, nfreq)
    psd = power.mean(axis=0)  # (ch, nfreq)
    sums = psd @ member  # (ch, 4): theta, alpha, beta, total
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = sums[:, :3] / sums[:, 3:4]
    # rounding noise of the detrend (a constant or a pure ramp) is not a spectrum: no relative power
    floor = 1e-12 * nperseg * (1.0 + np.max(np.abs(x), axis=0) ** 2)
    rel[~(sums[:, 3] > floor)] = np.nan
    return rel


def engagement_index(theta: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """``E = beta / (alpha + theta)``, elementwise; NaN where ``alpha + theta`` is 0."""
    theta, alpha, beta = (np.asarray(v, dtype=float) for v in (theta, alpha, beta))
    denom = alpha + theta
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(denom != 0, beta / np.where(denom != 0, denom, 1.0), np.nan)
    return out


# ----------------------------------------------------------------------------------------------
# Smoothing
# ----------------------------------------------------------------------------------------------


def _check_a(a: float) -> float:
    a = float(a)
    if not 0.0 <= a < 1.0:
        raise ValueError(f"EWMA factor a must be in [0, 1), got {a}")
    return a


def ewma(y: np.ndarray, a: float, s0: "float | np.ndarray | None" = None) -> np.ndarray:
    """Exponentially weighted moving average along axis 0: ``s_t = a * s_(t-1) + (1 - a) * y_t``.

    ``s_0 = y_0`` for a fresh series; pass ``s0`` (the last smoothed value) to continue a stream, then
    ``s_0 = a * s0 + (1 - a) * y_0``. ``y`` may be ``(n,)`` or ``(n, k)``. NaN propagates: filter
    unusable values out first (the online estimator holds its state over them instead).
    """
    from scipy.signal import lfilter  # lazy: scipy is heavy to import

    a = _check_a(a)
    y = np.asarray(y, dtype=float)
    if y.shape[0] == 0:
        return y.copy()
    init = y[0] if s0 is None else np.broadcast_to(np.asarray(s0, dtype=float), y.shape[1:])
    zi = (a * np.asarray(init, dtype=float))[None, ...]
    out, _ = lfilter([1.0 - a], [1.0, -a], y, axis=0, zi=zi)
    return out


def lagged_ewma_authors2018(y: np.ndarray, a: float = 0.9) -> np.ndarray:
    """The smoothing of the authors' published code: ``S[0] = Y[0]; S[i] = (1-a) Y[i-1] + a S[i-1]``.

    Lagged by one sample compared with :func:`ewma` (``S[i]`` does not yet contain ``Y[i]``); kept only
    to reproduce their tables (``--compat authors2018``). Works along axis 0 like :func:`ewma`.
    """
    y = np.asarray(y, dtype=float)
    if y.shape[0] <= 1:
        return y.copy()
    rest = ewma(y[:-1], a, s0=y[0])  # S[1] = (1-a) Y[0] + a Y[0] = Y[0], then the recurrence
    return np.concatenate([y[:1], rest], axis=0)


class Ewma:
    """Streaming :func:`ewma`: ``update(y)`` returns the new smoothed value.

    A non-finite ``y`` leaves the state unchanged and returns NaN (no value is invented for it).
    """

    def __init__(self, a: float) -> None:
        self.a = _check_a(a)
        self.value: float | None = None

    def update(self, y: float) -> float:
        y = float(y)
        if not np.isfinite(y):
            return float("nan")
        self.value = y if self.value is None else self.a * self.value + (1.0 - self.a) * y
        return self.value

    def reset(self) -> None:
        self.value = None


# ----------------------------------------------------------------------------------------------
# Signal quality
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class QualityThresholds:
    """When a channel's window is not clean EEG. Checked in this order; the first failure is the reason.

    * ``non-finite``: any NaN/inf sample.
    * ``flat``: standard deviation of the linearly detrended window below ``min_std_uv``
      (electrode off the skin, or a dead channel; real EEG has several uV).
    * ``saturated``: the signal sits at one value for ``max_constant_s`` or longer (an amplifier at its
      rail), or - when ``rail_low``/``rail_high`` are set - any sample at or beyond a rail.
    * ``implausible amplitude``: detrended standard deviation above ``max_std_uv`` or peak-to-peak
      above ``max_ptp_uv`` (movement, loose electrode; blinks reach ~100-200 uV at AF7/AF8).
    """

    min_std_uv: float = 1.0
    max_std_uv: float = 100.0
    max_ptp_uv: float = 600.0
    max_constant_s: float = 0.1
    rail_low: float | None = None
    rail_high: float | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.min_std_uv < self.max_std_uv:
            raise ValueError(f"need 0 <= min_std_uv < max_std_uv, got {self.min_std_uv}, {self.max_std_uv}")
        if self.max_ptp_uv <= 0 or self.max_constant_s <= 0:
            raise ValueError("max_ptp_uv and max_constant_s must be > 0")


def _longest_constant_run(x: np.ndarray) -> np.ndarray:
    """Per column, the longest number of consecutive equal samples (vectorised)."""
    n, ch = x.shape
    if n < 2:
        return np.ones(ch, dtype=int)
    same = np.diff(x, axis=0) == 0  # (n-1, ch)
    # run length of True ending at each row: index minus index of the last False so far
    idx = np.arange(1, n)[:, None]
    last_break = np.maximum.accumulate(np.where(~same, idx, 0), axis=0)
    return (idx - last_break).max(axis=0) + 1


def window_quality(
    x: np.ndarray, fs: float, thresholds: QualityThresholds = QualityThresholds()
) -> tuple[np.ndarray, list[str]]:
    """Per channel: is this window of raw EEG clean, and if not, why.

    Returns ``(clean, reasons)``: ``clean`` a bool array ``(n_channels,)`` and ``reasons`` one string per
    channel, empty when clean, else "non-finite", "flat", "saturated" or "implausible amplitude".
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n, ch = x.shape
    reasons = [""] * ch
    finite = np.isfinite(x).all(axis=0)
    xs = np.where(np.isfinite(x), x, 0.0)
    t = np.arange(n, dtype=float) - (n - 1) / 2.0
    slope = (t @ (xs - xs.mean(axis=0))) / max(float(t @ t), 1e-12)
    resid = xs - xs.mean(axis=0) - np.outer(t, slope)
    std = resid.std(axis=0)
    ptp = resid.max(axis=0) - resid.min(axis=0) if n else np.zeros(ch)
    run = _longest_constant_run(xs)
    saturated = run >= max(2, int(round(thresholds.max_constant_s * fs)))
    if thresholds.rail_low is not None:
        saturated |= (xs <= thresholds.rail_low).any(axis=0)
    if thresholds.rail_high is not None:
        saturated |= (xs >= thresholds.rail_high).any(axis=0)
    flat = std < thresholds.min_std_uv
    implausible = (std > thresholds.max_std_uv) | (ptp > thresholds.max_ptp_uv)
    for c in range(ch):
        if not finite[c]:
            reasons[c] = "non-finite"
        elif flat[c]:
            reasons[c] = "flat"
        elif saturated[c]:
            reasons[c] = "saturated"
        elif implausible[c]:
            reasons[c] = "implausible amplitude"
    clean = np.array([r == "" for r in reasons], dtype=bool)
    return clean, reasons


# ----------------------------------------------------------------------------------------------
# Online estimator
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WindowResult:
    """One analysis window. ``index_raw``/``index_smoothed`` are None when the window is unusable."""

    t_end: float
    index_raw: float | None
    index_smoothed: float | None
    clean_fraction: float  # fraction of scalp channels that were clean (0 for a gap)
    reason: str = ""  # why the index is None, or "gap ..." for a reported gap

    @property
    def usable(self) -> bool:
        return self.index_raw is not None


class OnlineEngagement:
    """Sliding-window engagement from a stream of raw EEG samples. Pure and stateful; no I/O.

    Every ``hop_s`` seconds of samples, the last ``window_s`` seconds are checked channel by channel
    (:func:`window_quality`); the clean channels' relative band powers (:func:`relative_band_powers`)
    are averaged and ``E = beta / (alpha + theta)`` computed, then smoothed with :class:`Ewma`.
    A window with fewer than ``min_clean_channels`` clean channels gives ``index_raw=None`` with the
    reason. A jump in timestamps larger than ``gap_factor`` sample periods is a gap: the buffer and
    the smoothing restart, a ``WindowResult`` with reason ``"gap <seconds> s"`` is emitted and the gap is
    appended to :attr:`gaps`. Windows are only computed every hop, so the cost stays small
    (256 Hz x 5 channels is well under 1 % of a core; see ``benchmarks/``).
    """

    def __init__(
        self,
        fs: float,
        n_channels: int,
        window_s: float = 2.0,
        hop_s: float = 0.25,
        a: float = 0.9,
        thresholds: QualityThresholds = QualityThresholds(),
        min_clean_channels: int = 2,
        gap_factor: float = 2.0,
        channel_names: Sequence[str] | None = None,
    ) -> None:
        if fs <= 0:
            raise ValueError(f"fs must be > 0, got {fs}")
        if n_channels < 1:
            raise ValueError(f"n_channels must be >= 1, got {n_channels}")
        if not 0 < hop_s <= window_s:
            raise ValueError(f"need 0 < hop_s <= window_s, got hop_s={hop_s}, window_s={window_s}")
        if not 1 <= min_clean_channels <= n_channels:
            raise ValueError(f"min_clean_channels must be in 1..{n_channels}, got {min_clean_channels}")
        if gap_factor <= 1:
            raise ValueError(f"gap_factor must be > 1, got {gap_factor}")
        self.fs = float(fs)
        self.n_channels = int(n_channels)
        self.window_n = max(8, int(round(window_s * fs)))
        self.hop_n = max(1, int(round(hop_s * fs)))
        self.thresholds = thresholds
        self.min_clean_channels = int(min_clean_channels)
        self.gap_s = gap_factor / self.fs
        self.channel_names = list(channel_names) if channel_names else [f"ch{i + 1}" for i in range(n_channels)]
        if len(self.channel_names) != n_channels:
            raise ValueError(f"{len(self.channel_names)} channel names for {n_channels} channels")
        self.smoother = Ewma(a)
        self.gaps: list[tuple[float, float]] = []  # (last timestamp before, first after)
        self._buf = np.empty((0, n_channels))
        self._ts = np.empty(0)
        self._since_window = 0  # samples since the last computed window (or since the restart)
        self._last_t: float | None = None

    def reset(self) -> None:
        """Forget buffered samples and the smoothing state (not the recorded gaps)."""
        self._buf = np.empty((0, self.n_channels))
        self._ts = np.empty(0)
        self._since_window = 0
        self._last_t = None
        self.smoother.reset()

    def push(self, samples: np.ndarray, timestamps: np.ndarray) -> list[WindowResult]:
        """Add ``samples`` ``(n, n_channels)`` stamped ``timestamps`` ``(n,)``; return completed windows."""
        x = np.asarray(samples, dtype=float)
        ts = np.asarray(timestamps, dtype=float).reshape(-1)
        if x.ndim != 2 or x.shape[1] != self.n_channels:
            raise ValueError(f"samples must be (n, {self.n_channels}), got shape {x.shape}")
        if ts.shape[0] != x.shape[0]:
            raise ValueError(f"{ts.shape[0]} timestamps for {x.shape[0]} samples")
        out: list[WindowResult] = []
        if x.shape[0] == 0:
            return out
        prev = np.concatenate([[self._last_t], ts[:-1]]) if self._last_t is not None else np.r_[ts[0], ts[:-1]]
        jumps = np.flatnonzero(np.abs(ts - prev) > self.gap_s)
        start = 0
        for j in list(jumps) + [x.shape[0]]:
            if j > start:
                out.extend(self._push_contiguous(x[start:j], ts[start:j]))
            if j < x.shape[0]:
                before = float(prev[j])
                self.gaps.append((before, float(ts[j])))
                self.reset()
                out.append(WindowResult(float(ts[j]), None, None, 0.0, f"gap {ts[j] - before:.2f} s"))
            start = j
        return out

    def _push_contiguous(self, x: np.ndarray, ts: np.ndarray) -> list[WindowResult]:
        self._last_t = float(ts[-1])
        buf = np.concatenate([self._buf, x], axis=0)
        tbuf = np.concatenate([self._ts, ts])
        n_old = self._buf.shape[0]
        out: list[WindowResult] = []
        # window ends (exclusive index into buf) fall every hop_n samples since the last window
        first_end = n_old + (self.hop_n - self._since_window)
        for end in range(first_end, buf.shape[0] + 1, self.hop_n):
            if end >= self.window_n:
                out.append(self._window(buf[end - self.window_n : end], float(tbuf[end - 1])))
        total_new = self._since_window + x.shape[0]
        self._since_window = total_new % self.hop_n
        keep = self.window_n - 1
        self._buf = buf[-keep:]
        self._ts = tbuf[-keep:]
        return out

    def _window(self, w: np.ndarray, t_end: float) -> WindowResult:
        clean, reasons = window_quality(w, self.fs, self.thresholds)
        self.last_clean = clean  # per-channel contact of the latest window (a supervisor's view)
        frac = float(clean.mean())
        if clean.sum() < self.min_clean_channels:
            bad = ", ".join(f"{n} {r}" for n, r in zip(self.channel_names, reasons) if r)
            reason = f"{int(clean.sum())} clean channels < {self.min_clean_channels} needed ({bad})"
            return WindowResult(t_end, None, None, frac, reason)
        rel = relative_band_powers(w[:, clean], self.fs)
        bands = np.nanmean(rel, axis=0) if np.isfinite(rel).any() else np.full(3, np.nan)
        e = float(engagement_index(bands[0], bands[1], bands[2]))
        if not np.isfinite(e):
            return WindowResult(t_end, None, None, frac, "no band power")
        s = self.smoother.update(e)
        return WindowResult(t_end, e, s, frac)
