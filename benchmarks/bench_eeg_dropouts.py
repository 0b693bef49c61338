"""EEG dropouts, many of them: how soon the monitor marks a stream lost and how soon it is back.

The suite drops a stream three times (5 s, 20 s, for good: tests/session/test_eeg_dropout.py); this
script repeats drops on one monitor, as a long session would meet them, for three kinds of dropout:

* ``pause``: a simulated Muse stops pushing and keeps its outlet (a headband out of range while
  muselsl runs);
* ``kill``: the simulated Muse's outlet is destroyed and a new one with the same source_id starts
  (muselsl restarted): liblsl's inlet recovery finds it;
* ``brainflow``: BrainFlow's synthetic board stops streaming underneath the device's bridge, which
  releases and prepares the board again (``reconnect_after_s``).

For each drop it prints the latency from the drop to ``eeg_stream_lost`` (expected: about
``loss_timeout_s`` + one poll), from the source's return to ``eeg_stream_restored``, and the gap the
monitor recorded against the true drop. At the end: how many gaps were recorded and whether every one
was closed.

Run: ``python benchmarks/bench_eeg_dropouts.py [--drops 5] [--drop-s 3] [--kinds pause,kill,brainflow]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np


def _wait(condition, limit_s: float = 120.0) -> float:
    """Seconds until ``condition()`` holds (raises after ``limit_s``)."""
    t0 = time.monotonic()
    while not condition():
        if time.monotonic() - t0 > limit_s:
            raise RuntimeError("timed out")
        time.sleep(0.005)
    return time.monotonic() - t0


def run_kind(kind: str, drops: int, drop_s: float) -> list[tuple[float, float, float]]:
    from nao_trainer.eeg.factory import open_monitor
    from nao_trainer.eeg.simulated_muse import SimulatedMuse

    proc = {"window_s": 1.0, "hop_s": 0.25, "loss_timeout_s": 0.5, "resolve_timeout_s": 10.0}
    folder = Path(tempfile.mkdtemp(prefix=f"bench-dropouts-{kind}-"))
    rng = np.random.default_rng(0)
    sim = None
    if kind == "brainflow":
        cfg = {"device": "brainflow", "processing": proc, "device_settings": {"reconnect_after_s": 1.0}}
        monitor = open_monitor("simulated", cfg, folder, rng, pseudonym="bench")
        bridge = monitor.simulator
    else:
        sid = f"MuseBench-{os.getpid()}-{uuid.uuid4().hex[:6]}"
        sim = SimulatedMuse.start(np.random.default_rng(1), source_id=sid)
        monitor = open_monitor("lsl", {"source_id": sid, "processing": proc}, folder, rng, pseudonym="bench")
    rows = []
    try:
        _wait(lambda: monitor.status == "streaming")
        for k in range(drops):
            n_gaps = len(monitor.gaps)
            t_drop = time.monotonic()
            if kind == "pause":
                sim.pause()
            elif kind == "kill":
                sim.stop()
            else:
                bridge.interrupt()
            lost = _wait(lambda: len(monitor.gaps) > n_gaps)
            if kind != "brainflow":  # the bridge brings the board back by itself, after reconnect_after_s
                time.sleep(max(0.0, drop_s - (time.monotonic() - t_drop)))
            if kind == "pause":
                sim.resume()
            elif kind == "kill":
                sim = SimulatedMuse.start(np.random.default_rng(2 + k), source_id=sid)
            back = _wait(lambda: monitor.gaps[-1].end is not None)
            g = monitor.gaps[-1]
            if kind == "brainflow":  # "back": from the interrupt, through the board's release and new session
                back = time.monotonic() - t_drop
            rows.append((lost, back, g.end - g.start))
            since = "after the interrupt" if kind == "brainflow" else "after the source returned"
            print(f"{kind:9s} drop {k + 1}: lost after {lost:5.2f} s, back {back:5.2f} s {since}, "
                  f"gap recorded {g.end - g.start:5.2f} s", flush=True)
            _wait(lambda: monitor.status == "streaming")
            time.sleep(1.0)
        closed = all(g.end is not None for g in monitor.gaps)
        print(f"{kind:9s} {len(monitor.gaps)} gaps recorded for {drops} drops, all closed: {closed}"
              + (f"; board reconnections {bridge.reconnects}" if kind == "brainflow" else ""), flush=True)
    finally:
        monitor.close()
        if sim is not None:
            sim.stop()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drops", type=int, default=5)
    ap.add_argument("--drop-s", type=float, default=3.0, help="how long each drop lasts (default 3)")
    ap.add_argument("--kinds", default="pause,kill,brainflow")
    args = ap.parse_args()
    os.environ.setdefault("QI_LOG_LEVEL", "silent")
    from nao_trainer.eeg.lsl_scope import configure_lsl

    print(f"LSL configuration: {configure_lsl('machine')}", file=sys.stderr)
    for kind in args.kinds.split(","):
        rows = run_kind(kind.strip(), args.drops, args.drop_s)
        a = np.array(rows)
        print(f"{kind:9s} median: lost after {np.median(a[:, 0]):.2f} s (max {a[:, 0].max():.2f}), back after "
              f"{np.median(a[:, 1]):.2f} s (max {a[:, 1].max():.2f}), gap {np.median(a[:, 2]):.2f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
