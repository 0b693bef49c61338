"""The measurements behind the engagement scale's rule (``core.phase.MIN_REL_SPAN``, docs/explanation/engagement.md).

Prints (1) the 5th-95th percentile span of the smoothed index at one constant engagement of the
simulated Muse, relative to its median, with the default 2 s windows and the demo's 0.5 s windows;
(2) for the 4 published raw sessions (band lines and raw EEG): the span of the listening phases'
smoothed index relative to its median, where the intro's median lies on that range, and how wide the
intro's own span is. Not a speed benchmark (``make bench`` runs only ``bench_*.py``).

    python benchmarks/measure_engagement_scale.py      # dataset from $NAO_TRAINER_SHARED or ../shared
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _data import extract, shared_dir  # noqa: E402
from nao_trainer.core.engagement import OnlineEngagement  # noqa: E402
from nao_trainer.core.phase import MIN_REL_SPAN  # noqa: E402
from nao_trainer.data import engagement as offline  # noqa: E402
from nao_trainer.eeg.simulated_muse import MUSE_CHUNK, MUSE_RATE_HZ, MuseSignal  # noqa: E402


def rel_span(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    lo, hi = np.percentile(v, [5, 95])
    return float((hi - lo) / np.median(v))


def simulated(target: float, window_s: float, hop_s: float, seconds: float = 60.0, seed: int = 3) -> float:
    """Relative 5-95 span of the smoothed index of the simulated Muse held at ``target``."""
    signal = MuseSignal(np.random.default_rng(seed), target=target)
    oe = OnlineEngagement(MUSE_RATE_HZ, 4, window_s=window_s, hop_s=hop_s, a=0.75)
    out, n = [], 0
    while n < seconds * MUSE_RATE_HZ:
        x = signal.next(MUSE_CHUNK)[:, :4]  # the scalp channels, as the monitor uses them
        out += oe.push(x, (n + np.arange(MUSE_CHUNK)) / MUSE_RATE_HZ)
        n += MUSE_CHUNK
    smooth = np.array([w.index_smoothed for w in out if w.usable], dtype=float)
    return rel_span(smooth[int(5 / hop_s):])  # after the first 5 s (the start-up glide)


def main() -> None:
    print(f"minimum span in use: {MIN_REL_SPAN} x median")
    print("simulated Muse, constant engagement: 5-95 % span / median of the smoothed index")
    for target in (0.19, 0.39, 0.5):
        print(f"  target {target:.2f}: 2 s windows {simulated(target, 2.0, 0.25):.2f}, "
              f"0.5 s windows (demo) {simulated(target, 0.5, 0.1):.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        root = extract(shared_dir() / "data" / "sequence-learning" / "raw_sessions.tar.xz", Path(tmp)) / "clean_data"
        print("published raw sessions: listening phases' span / median; intro median on that range; intro span / task span")
        for sdir in sorted(root.glob("user_*/session_*")):
            for src in ("bands", "raw"):
                r = offline.session_engagement(sdir, source=src)
                task = np.concatenate([s.smoothed for s in r.series.values()])
                task = task[np.isfinite(task)]
                base = offline._baseline_values(sdir, src, offline.OfflineSettings())
                base = base[np.isfinite(base)]
                lo, hi = np.percentile(task, [5, 95])
                blo, bhi = np.percentile(base, [5, 95])
                print(f"  {sdir.parent.name}/{sdir.name} {src:5}: span {rel_span(task):.2f} x median, "
                      f"intro at {(np.median(base) - lo) / (hi - lo):.2f}, intro span {(bhi - blo) / (hi - lo):.1f} x")


if __name__ == "__main__":
    main()
