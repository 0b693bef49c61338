"""Benchmark of the engagement maths and the offline reader (prints figures; never a timed test).

Targets (issue 3): per-turn engagement for all 50 published sessions <= 10 s; the online estimator at
256 Hz x 5 channels <= 1 % of one core; end of a listening phase -> its per-turn value <= 50 ms.

    python benchmarks/bench_engagement_offline.py       # dataset from $NAO_TRAINER_SHARED or ../shared
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nao_trainer.core import engagement as core  # noqa: E402
from nao_trainer.core import phase  # noqa: E402
from nao_trainer.data import engagement as offline  # noqa: E402


def _extract(tmp: Path) -> tuple[Path, Path]:
    shared = Path(os.environ.get("NAO_TRAINER_SHARED", ROOT.parent / "shared"))
    data = shared / "data" / "sequence-learning"
    out = []
    for archive, sub in (("clean_data_bands.tar.xz", "bands"), ("raw_sessions.tar.xz", "raw")):
        dest = tmp / sub
        dest.mkdir()
        print(f"extracting {data / archive} ...", file=sys.stderr, flush=True)
        subprocess.run(["tar", "-xJf", str(data / archive), "-C", str(dest)], check=True)
        out.append(dest / "clean_data")
    return out[0], out[1]


def bench_offline(bands_root: Path, raw_root: Path) -> None:
    for compat in ("authors2018", None):
        for workers in (1, 2):
            t0, c0 = time.perf_counter(), time.process_time()
            res = offline.session_engagement_many(bands_root, compat=compat, workers=workers)
            dt, cpu = time.perf_counter() - t0, time.process_time() - c0
            n = sum(len(r.turns) for r in res)
            own = f", {cpu:.2f} s CPU" if workers == 1 else ""  # the pool's CPU is in its children
            print(f"offline {compat or 'project':12s} bands, {len(res)} sessions / {n} turns, "
                  f"{workers} worker(s): {dt:6.2f} s wall{own}   (target <= 10 s)")
    t0 = time.perf_counter()
    res = offline.session_engagement_many(raw_root, source="raw", workers=2)
    dt = time.perf_counter() - t0
    print(f"offline project      raw EEG, {len(res)} sessions (with intro baselines), 2 workers: {dt:6.2f} s")


def _synthetic(rng: np.random.Generator, seconds: float, fs: float = 256.0, ch: int = 5) -> np.ndarray:
    n = int(seconds * fs)
    t = np.arange(n) / fs
    x = 850 + rng.normal(0, 8, (n, ch))
    for f, a in ((6.0, 6.0), (10.0, 10.0), (20.0, 5.0)):
        x += a * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 6.3, ch))
    return x


def bench_online() -> None:
    fs, ch, chunk, seconds = 256.0, 5, 12, 300.0
    rng = np.random.default_rng(0)
    x = _synthetic(rng, seconds, fs, ch)
    ts = np.arange(len(x)) / fs
    est = core.OnlineEngagement(fs, ch)
    c0, w0 = time.process_time(), time.perf_counter()
    n_windows = 0
    for i in range(0, len(x), chunk):
        n_windows += len(est.push(x[i : i + chunk], ts[i : i + chunk]))
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    print(f"online estimator 256 Hz x {ch} ch, chunks of {chunk}: {seconds:.0f} s of EEG in {cpu:.3f} s CPU "
          f"({wall:.3f} s wall), {n_windows} windows -> {100 * cpu / seconds:.3f} % of one core (target <= 1 %)")

    # latency: a 10 s listening phase streamed in chunks; at its end, push the last chunk and aggregate
    est = core.OnlineEngagement(fs, ch)
    norm = phase.EngagementNormaliser().fit_baseline(rng.normal(0.5, 0.1, 240))
    phase_n = int(10 * fs)
    lat = []
    windows: list[core.WindowResult] = []
    for p in range(int(seconds // 10)):
        a, b = p * phase_n, (p + 1) * phase_n
        for i in range(a, b - chunk, chunk):
            windows += est.push(x[i : i + chunk], ts[i : i + chunk])
        t0 = time.perf_counter()
        windows += est.push(x[b - chunk : b], ts[b - chunk : b])
        agg = phase.aggregate_phase(windows, ts[a], ts[b - 1], 0.25, norm, 0.5)
        norm.extend([w.index_smoothed for w in windows if w.t_end > ts[a] and w.usable])
        lat.append(time.perf_counter() - t0)
        windows = windows[-8:]
        assert agg.index is not None
    lat_ms = 1000 * np.array(lat)
    print(f"end of phase -> per-turn value: median {np.median(lat_ms):.2f} ms, max {lat_ms.max():.2f} ms "
          f"over {len(lat)} phases (target <= 50 ms)")


def main() -> int:
    print(f"load average: {' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores "
          "(wall times grow with other work on the machine)")
    bench_online()
    with tempfile.TemporaryDirectory() as tmp:
        bands_root, raw_root = _extract(Path(tmp))
        bench_offline(bands_root, raw_root)
    return 0


if __name__ == "__main__":
    sys.exit(main())
