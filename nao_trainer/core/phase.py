"""From analysis windows to one value per phase: per-participant normalisation, phase aggregation, summary.

Pure (no I/O, no clock): the live monitor (``eeg/monitor.py``) and the offline pipeline
(``data/engagement.py``) both call these, so a phase is summarised the same way in both.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from nao_trainer.core.engagement import WindowResult


# ----------------------------------------------------------------------------------------------
# Normalisation
# ----------------------------------------------------------------------------------------------


#: Smallest span of the scale, as a fraction of the median of the values it is taken from. The index is
#: a power ratio whose noise grows with its level: at a constant engagement the 5th-95th percentile span
#: of the smoothed index is ~9 % of its median with 2 s windows and ~18 % with the demo's 0.5 s windows
#: (simulated Muse), while real sessions span 84-234 % over their listening phases (the 4 published raw
#: sessions, band lines and raw EEG; benchmarks/measure_engagement_scale.py prints these). Below this
#: span the scale is widened around its centre, so a
#: participant whose engagement does not change is shown near the middle, not as noise stretched to [0, 1].
MIN_REL_SPAN = 0.3


@dataclass
class EngagementNormaliser:
    """Per-participant scaling of the engagement index to [0, 1] over the task.

    Rule: the bounds are the ``lo_q``-th and ``hi_q``-th percentiles (default 5th/95th) of the task
    values seen so far (each value passed to :meth:`update` or :meth:`extend`), and
    ``normalised = clip((v - lo) / (hi - lo), 0, 1)``: like the paper's per-user scaling of the session
    to [0, 1], but causal (running). The baseline (greeting and instructions, :meth:`fit_baseline`) is
    the reference, not part of the range: it supplies the scale until the task has ``min_values``
    values, and :attr:`baseline_position` says where rest lies on the task's scale. A resting
    baseline far above or below the task therefore cannot pin every task value at 0 or 1.
    Percentiles rather than min/max keep one artefact from squashing the whole scale. A span below
    ``min_rel_span`` x the median of the values is widened to it around its centre (noise is not
    stretched over the scale). With fewer than ``min_values`` values (task, or else baseline), or
    ``hi - lo < min_span``, there is no scale and the result is NaN, never an invented number.
    """

    lo_q: float = 5.0
    hi_q: float = 95.0
    min_values: int = 5
    min_rel_span: float = MIN_REL_SPAN
    min_span: float = 1e-9
    history: list[float] = field(default_factory=list, repr=False, init=False)  # task values
    baseline: list[float] = field(default_factory=list, repr=False, init=False)  # the reference
    baseline_n_: int = field(default=0, init=False)
    lo_: float = field(default=float("nan"), init=False)
    hi_: float = field(default=float("nan"), init=False)
    scale_from_: str = field(default="", init=False)  # "task", "baseline" or "" (no scale yet)

    def __post_init__(self) -> None:
        if not 0 <= self.lo_q < self.hi_q <= 100:
            raise ValueError(f"need 0 <= lo_q < hi_q <= 100, got {self.lo_q}, {self.hi_q}")
        if self.min_values < 2:
            raise ValueError(f"min_values must be >= 2, got {self.min_values}")
        if self.min_rel_span < 0:
            raise ValueError(f"min_rel_span must be >= 0, got {self.min_rel_span}")

    def _refresh(self) -> None:
        for name, values in (("task", self.history), ("baseline", self.baseline)):
            if len(values) >= self.min_values:
                v = np.asarray(values)
                lo, hi = (float(x) for x in np.percentile(v, [self.lo_q, self.hi_q]))
                least = self.min_rel_span * abs(float(np.median(v)))
                if hi - lo < least:
                    mid = (lo + hi) / 2
                    lo, hi = mid - least / 2, mid + least / 2
                self.lo_, self.hi_, self.scale_from_ = lo, hi, name
                return
        self.lo_, self.hi_, self.scale_from_ = float("nan"), float("nan"), ""

    def fit_baseline(self, values: Iterable[float]) -> "EngagementNormaliser":
        """Set the reference (baseline) values (non-finite ones are ignored) and clear the task values.

        Returns self. The baseline is the scale until the task has ``min_values`` values.
        """
        v = np.asarray(list(values), dtype=float)
        self.baseline = [float(x) for x in v[np.isfinite(v)]]
        self.history = []
        self.baseline_n_ = len(self.baseline)
        self._refresh()
        return self

    def update(self, value: float) -> float:
        """Add a task value to the running bounds and return it normalised with the updated bounds."""
        return float(self.extend(np.array([float(value)]))[0])

    def extend(self, values: Iterable[float]) -> np.ndarray:
        """Add a batch of task values (e.g. one phase) to the running bounds, then return them normalised.

        Same rule as calling :meth:`update` for each, but the bounds are refreshed once, after the batch.
        """
        v = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=float)
        self.history.extend(float(x) for x in v[np.isfinite(v)])
        self._refresh()
        return self.normalise(v)

    @property
    def ready(self) -> bool:
        return bool(np.isfinite(self.lo_) and self.hi_ - self.lo_ >= self.min_span)

    @property
    def baseline_position(self) -> float | None:
        """The baseline's median on the current scale, not clipped (e.g. 2.4 = far above the task's range).

        None without a baseline or a scale.
        """
        if not self.baseline or not self.ready:
            return None
        return (float(np.median(self.baseline)) - self.lo_) / (self.hi_ - self.lo_)

    def normalise(self, values: np.ndarray) -> np.ndarray:
        """Scale with the current bounds (does not update them); NaN when not ready or v is NaN."""
        v = np.asarray(values, dtype=float)
        if not self.ready:
            return np.full(v.shape, np.nan)
        return np.clip((v - self.lo_) / (self.hi_ - self.lo_), 0.0, 1.0)


def minmax_scale(values: np.ndarray) -> np.ndarray:
    """Min-max scale over all finite values (the authors' session-wide normalisation); NaN stays NaN."""
    v = np.asarray(values, dtype=float)
    lo, hi = np.nanmin(v), np.nanmax(v)
    if not hi > lo:
        return np.full(v.shape, np.nan)
    return (v - lo) / (hi - lo)


# ----------------------------------------------------------------------------------------------
# Per-phase aggregation
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PhaseAggregate:
    """A phase's engagement: means over its usable windows, the clean fraction, or why it is empty."""

    index: float | None  # mean raw E of the usable windows
    smoothed: float | None  # mean smoothed E of the usable windows
    engagement: float | None  # mean normalised smoothed E (when a normaliser was given)
    quality: float  # clean fraction of the phase, 0..1
    n_windows: int
    reason: str = ""


def aggregate_phase(
    windows: Sequence[WindowResult],
    t0: float,
    t1: float,
    hop_s: float,
    normaliser: EngagementNormaliser | None = None,
    min_quality: float = 0.5,
) -> PhaseAggregate:
    """Aggregate the windows ending in ``(t0, t1]`` into one phase value.

    ``quality`` = sum of the windows' clean fractions (0 for unusable windows) divided by the number of
    windows the phase should have had (``(t1 - t0) / hop_s``, at least the number present), so lost
    samples lower it too. Below ``min_quality`` the phase is empty, with the reason.
    """
    if t1 < t0:
        raise ValueError(f"phase ends before it starts: t0={t0}, t1={t1}")
    inside = [w for w in windows if t0 < w.t_end <= t1]
    usable = [w for w in inside if w.usable]
    expected = max(len(inside), int(np.floor((t1 - t0) / hop_s + 1e-9)), 1)
    quality = float(sum(w.clean_fraction for w in usable) / expected)
    if not usable:
        why = inside[-1].reason if inside else "no EEG windows in the phase"
        return PhaseAggregate(None, None, None, quality, len(inside), f"no clean signal: {why}")
    if quality < min_quality:
        return PhaseAggregate(
            None, None, None, quality, len(inside), f"only {quality:.0%} clean signal (needs {min_quality:.0%})"
        )
    raw = np.array([w.index_raw for w in usable], dtype=float)
    smooth = np.array([w.index_smoothed for w in usable], dtype=float)
    eng = None
    if normaliser is not None:
        norm = normaliser.normalise(smooth)
        eng = float(np.mean(norm)) if np.isfinite(norm).all() else None
    return PhaseAggregate(float(raw.mean()), float(smooth.mean()), eng, quality, len(inside))



# ----------------------------------------------------------------------------------------------
# Summary of a live phase
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PhaseSummary:
    """A phase's engagement (normalised), raw index and clean fraction, or why there is no value.

    ``smoothed`` and ``normalised`` hold one value per window of the phase (NaN for unusable ones).
    """

    engagement: float | None
    index: float | None
    quality: float
    reason: str
    smoothed: np.ndarray
    normalised: np.ndarray


def summarise_phase(windows: Sequence[WindowResult], t0: float, t1: float, normaliser: EngagementNormaliser,
                    baseline: bool, had_baseline: bool, hop_s: float, min_quality: float,
                    lost_s: float = 0.0, unavailable: str | None = None) -> PhaseSummary:
    """Summarise the windows of one phase and update ``normaliser`` with them.

    A baseline phase sets the normaliser's reference (its scale until the task has enough values); any
    other phase joins the task values of the running bounds.
    The phase value is the mean normalised smoothed E of its usable windows, normalised once with
    the updated bounds. ``had_baseline``: a baseline phase was summarised (this one included);
    ``lost_s``: seconds of the phase without stream; ``unavailable``: why there is no stream at all.
    """
    smooth = np.array([w.index_smoothed if w.usable else np.nan for w in windows], dtype=float)
    finite = smooth[np.isfinite(smooth)]
    if baseline:
        normaliser.fit_baseline(finite)
    else:  # running bounds: every phase's windows join the scale's history
        normaliser.extend(finite)
    agg = aggregate_phase(windows, t0, t1, hop_s, None, min_quality)
    norm = normaliser.normalise(smooth)  # once, for the phase value and the window rows
    engagement = None
    if agg.index is not None:
        usable = norm[np.array([w.usable for w in windows], dtype=bool)]
        if np.isfinite(usable).all():  # as aggregate_phase computes it from a normaliser
            engagement = float(np.mean(usable))
    reason = agg.reason
    if unavailable is not None:
        reason = f"EEG unavailable: {unavailable or 'no stream'}"
    elif agg.index is None and lost_s > 0:
        reason = f"stream lost for {lost_s:.1f} s of the phase ({reason})"
    elif engagement is None and agg.index is not None:
        why = (f"baseline too short: {normaliser.baseline_n_} usable windows" if had_baseline
               else "no baseline phase")
        reason = (f"no normalisation scale yet ({len(normaliser.history)} task windows seen, "
                  f"{normaliser.min_values} needed; {why})"
                  if not normaliser.scale_from_ else "normalisation scale is flat")
    return PhaseSummary(engagement, agg.index, agg.quality, "" if engagement is not None else reason, smooth, norm)
