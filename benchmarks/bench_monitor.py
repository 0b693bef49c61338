"""Live EEG monitor: CPU at 256 Hz x 5 channels and latency from a phase end to its engagement.

A simulated Muse runs in another process (``nao-trainer simulate-muse``) and publishes over LSL in
machine scope; this process runs the engagement monitor on it exactly as a session does (session
files written, raw samples recorded) and prints:

* the monitor thread's CPU time as % of one core (target <= 1 %), and the whole process's;
* the latency from ``end_phase()`` being called at the end of a listening phase to the returned
  per-turn engagement, median and max over the phases (target <= 50 ms).

Run: ``python benchmarks/bench_monitor.py [--seconds 20] [--phases 20]`` (LSLAPICFG is honoured;
without it the project's machine scope applies).
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="CPU measurement length (default 20)")
    ap.add_argument("--phases", type=int, default=20, help="listening phases for the latency (default 20)")
    ap.add_argument("--phase-s", type=float, default=1.0, help="length of each phase (default 1.0)")
    args = ap.parse_args()

    os.environ.setdefault("QI_LOG_LEVEL", "silent")
    from nao_trainer.eeg.lsl_scope import configure_lsl
    from nao_trainer.eeg.factory import open_monitor

    print(f"LSL configuration: {configure_lsl('machine')}", file=sys.stderr)
    sid = f"MuseBench-{uuid.uuid4().hex[:8]}"
    muse = subprocess.Popen([sys.executable, "-m", "nao_trainer", "simulate-muse", "--seed", "1", "--source-id", sid],
                            stderr=subprocess.PIPE, text=True)
    try:
        print(muse.stderr.readline().strip(), file=sys.stderr)
        with tempfile.TemporaryDirectory() as tmp:
            monitor = open_monitor("lsl", {"source_id": sid, "stream_name": None}, Path(tmp),
                                   np.random.default_rng(0), pseudonym="bench")
            try:
                cpu = measure_cpu(monitor, args.seconds)
                lat = measure_latency(monitor, args.phases, args.phase_s)
            finally:
                monitor.close()
    finally:
        muse.terminate()
        muse.wait(10)

    thread_pct, process_pct, rate, n_ch = cpu
    lat, lag = lat
    print(f"stream: {rate:.0f} Hz x {n_ch} channels (monitor uses the 4 scalp channels)")
    print(f"monitor thread CPU: {thread_pct:.2f} % of one core over {args.seconds:g} s (target <= 1 %)"
          f"  [{'OK' if thread_pct <= 1.0 else 'OVER'}]")
    print(f"whole process CPU:  {process_pct:.2f} % of one core (monitor thread + LSL's own threads)")
    print(f"phase end -> engagement latency over {len(lat)} phases: median {np.median(lat) * 1e3:.1f} ms, "
          f"max {np.max(lat) * 1e3:.1f} ms (target <= 50 ms)  [{'OK' if np.max(lat) <= 0.05 else 'OVER'}]")
    print(f"last window of each phase ended {np.median(lag) * 1e3:.0f} ms (median), {np.max(lag) * 1e3:.0f} ms (max) "
          f"before the phase end (hop {monitor.proc.hop_s * 1e3:.0f} ms)  "
          f"[{'OK: no window up to the end was missed' if np.max(lag) < monitor.proc.hop_s else 'MISSED WINDOWS'}]")
    return 0


def measure_cpu(monitor, seconds: float) -> tuple[float, float, float, int]:
    """CPU of the monitor thread (its own thread_time) and of the process, while it just streams."""
    if not monitor.wait_for_windows(1, 10.0):
        raise SystemExit("the monitor received no EEG windows; is the simulated Muse running?")
    t_cpu0, r0, w0 = monitor.thread_cpu_s, resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    time.sleep(seconds)
    t_cpu1, r1, w1 = monitor.thread_cpu_s, resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    wall = w1 - w0
    proc = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return 100 * (t_cpu1 - t_cpu0) / wall, 100 * proc / wall, monitor.inlet.fs, monitor.inlet.n_channels


def measure_latency(monitor, n: int, phase_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Seconds from calling end_phase() at a listening phase's end to holding its engagement, and how
    far before the phase end its last window ended (< hop: no window up to the end was missed)."""
    monitor.begin_phase("baseline", None)
    time.sleep(2.0)
    monitor.end_phase()
    out, lag = [], []
    for turn in range(1, n + 1):
        monitor.set_target(None)
        monitor.begin_phase("listening", turn)
        time.sleep(phase_s)
        t0 = time.perf_counter()
        result = monitor.end_phase()
        out.append(time.perf_counter() - t0)
        _, t1, _ = monitor.phases[-1]
        lag.append(t1 - max(w.t_end for w in monitor.windows if w.t_end <= t1))
        if result.index is None:
            print(f"phase {turn}: no engagement ({result.reason})", file=sys.stderr)
    return np.array(out), np.array(lag)


if __name__ == "__main__":
    sys.exit(main())
