"""`nao-trainer simulate-muse`: publish a simulated (or replayed) Muse EEG stream over LSL."""
from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from nao_trainer.eeg.lsl_scope import configure_lsl
from nao_trainer.errors import ConfigError, Interrupted


def register(sub) -> None:
    p = sub.add_parser(
        "simulate-muse",
        help="publish a muselsl-compatible EEG stream (simulated, or replaying a recorded session)",
        description=(
            "Publish an LSL stream laid out like muselsl's (name Muse, type EEG, TP9 AF7 AF8 TP10 Right AUX, "
            "256 Hz) whose band content shows the given engagement, or replay a recorded session: the eeg/raw.csv of "
            "a folder written by `nao-trainer run` at its recorded rate, or the raw 'eeg' lines of a published "
            "session folder (intro, robot_N, user_N) at 220 Hz. Runs until Ctrl-C or --duration (exit 130 after "
            "Ctrl-C or SIGTERM, 0 after --duration). The stream says what it is in its LSL description "
            "(desc/acquisition: simulated or replayed): a session where a person answers refuses it (exit 4) "
            "unless run with --allow-simulated-eeg. "
            "LSL stays on this machine unless --lsl-scope widens it."
        ),
    )
    p.add_argument("--engagement", type=float, default=0.5, metavar="X",
                   help="target engagement in [0, 1] the signal shows (default 0.5)")
    p.add_argument("--seed", type=int, default=None, help="seed of the signal (default: drawn and printed)")
    p.add_argument("--replay", type=Path, default=None, metavar="SESSION_DIR",
                   help="replay a session folder written by `nao-trainer run` (its eeg/raw.csv), a study folder of them "
                   "(one after another), or a raw published session folder, instead of simulating")
    p.add_argument("--loop", action="store_true", help="with --replay: start over at the end")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--source-id", default=None, metavar="ID",
                   help="LSL source_id (default Muse<fake MAC>; keep it to let inlets reconnect after a restart)")
    p.add_argument("--name", default="Muse", help="LSL stream name (default Muse)")
    p.add_argument("--wall-clock", action="store_true",
                   help="stamp samples with time.time() like muselsl without --lsltime")
    p.add_argument("--lsl-scope", default="machine",
                   choices=("machine", "link", "site", "organization", "global"),
                   help="LSL discovery scope (default machine: nothing leaves this computer)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from nao_trainer.eeg.simulated_muse import ReplayMuse, SimulatedMuse

    if not 0.0 <= args.engagement <= 1.0:
        raise ConfigError(f"--engagement: {args.engagement} is outside [0, 1]; give a value between 0 and 1")
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration: {args.duration} must be > 0 seconds")
    configure_lsl(args.lsl_scope)
    stop = {"flag": False}

    def on_signal(signum, frame):  # Ctrl-C / SIGTERM: stop cleanly, exit 130 like every command (README)
        stop["flag"] = True

    old_int = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    try:
        if args.replay is not None:
            pub = ReplayMuse.start(args.replay, name=args.name, source_id=args.source_id, loop=args.loop,
                                   wall_clock=args.wall_clock, scope=args.lsl_scope)
            what = (f"replaying {args.replay} ({len(pub.data)} samples, {len(pub.boundaries)} files, "
                    f"{len(pub.data) / pub.fs:.0f} s at {pub.fs:g} Hz)")
        else:
            seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % (2**32))
            pub = SimulatedMuse.start(np.random.default_rng(seed), target=args.engagement, name=args.name,
                                      source_id=args.source_id, wall_clock=args.wall_clock, scope=args.lsl_scope)
            what = f"simulating engagement {args.engagement:g} (seed {seed}) at {pub.fs:g} Hz"
        print(f"simulate-muse: ready: stream {pub.name!r} type 'EEG' source_id {pub.source_id!r}, {what}; "
              f"LSL scope {args.lsl_scope}; Ctrl-C to stop", file=sys.stderr, flush=True)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        try:
            while not stop["flag"] and pub.running:
                if t_end is not None and time.monotonic() >= t_end:
                    break
                time.sleep(0.05)
        finally:
            pub.stop()
        if pub.error is not None:
            raise pub.error
        print(f"simulate-muse: stopped after {pub.samples_pushed} samples", file=sys.stderr)
        return Interrupted.exit_code if stop["flag"] else 0
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
