"""`nao-trainer check --config F`: the pre-session check (robot, EEG contact, disk), one line per check."""
from __future__ import annotations

import argparse
from pathlib import Path

from nao_trainer.eeg.settings import MODES as EEG_MODES
from nao_trainer.errors import ConfigError
from nao_trainer.session.config import INPUTS, load_config


def register(sub) -> None:
    p = sub.add_parser(
        "check",
        help="check the robot, the EEG headband and the disk before a session",
        description="Check what a session of the study needs: the robot answers with the services the task uses, "
                    "its system volume is up and not muted and its battery charged; the EEG stream is found and "
                    "each electrode is in contact "
                    "(judged over a few seconds with the session's quality rules); there is disk space. One line "
                    "per check, OK or FAIL with the fix. Exit code: 0 when every required check passed, else "
                    "3 (robot), 4 (required EEG) or 2 (disk).",
    )
    p.add_argument("--config", metavar="FILE", help="study configuration (default: config/studies/demo.yaml)")
    p.add_argument("--robot", metavar="mock|desktop|URL", help="robot address (overrides robot.url)")
    p.add_argument("--eeg", choices=EEG_MODES, help="EEG mode (overrides eeg.mode)")
    p.add_argument("--eeg-device", metavar="NAME", help="EEG device plug-in (overrides eeg.device)")
    p.add_argument("--robot-model", metavar="NAME", help="robot model plug-in: nao, pepper (overrides robot.model)")
    p.add_argument("--allow-simulated-eeg", action="store_true",
                   help="pilots only: accept a simulated or replayed stream (simulate-muse) for a session where a "
                        "person answers or a real robot plays (eeg.allow_simulated)")
    p.add_argument("--eeg-source-id", metavar="ID", help="the LSL source_id of the headband (overrides eeg.source_id)")
    p.add_argument("--input", choices=INPUTS, help="answer input (overrides answers.input)")
    p.add_argument("--out", metavar="DIR", help="folder under which session folders are created (overrides session.output)")
    p.add_argument("--seconds", type=float, default=3.0, metavar="S", help="how long to judge electrode contact (default 3)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nao_trainer.session.check import exit_code, plan_from_config, run_checks

    if not 0.5 <= args.seconds <= 60:
        raise ConfigError(f"--seconds must be between 0.5 and 60, got {args.seconds:g}")
    overrides = {"robot.url": args.robot, "eeg.mode": args.eeg, "eeg.device": args.eeg_device, "robot.model": args.robot_model, "eeg.source_id": args.eeg_source_id,
                 "eeg.allow_simulated": True if args.allow_simulated_eeg else None, "answers.input": args.input,
                 "session.output": str(Path(args.out).resolve()) if args.out else None}
    config = load_config(args.config, overrides)
    results = run_checks(plan_from_config(config), report=lambda r: print(r.line(), flush=True),
                         eeg_listen_s=args.seconds)
    return exit_code(results)
