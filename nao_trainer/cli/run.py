"""`nao-trainer run`: play one training session (by default the demo study against the stand-in)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nao_trainer.eeg.settings import MODES as EEG_MODES
from nao_trainer.errors import ConfigError
from nao_trainer.robot.address import redact_url
from nao_trainer.session.config import INPUTS, is_robot_address, load_config


def register(sub) -> None:
    p = sub.add_parser(
        "run",
        help="play a training session (no flags: the demo study against the NAO stand-in)",
        description="Play one training session. With no flags: the demo study (config/studies/demo.yaml), "
                    "the NAO stand-in started in this process, a simulated participant, 25 sped-up turns. "
                    "Flags override the study configuration.",
    )
    p.add_argument("--config", metavar="FILE", help="study configuration (default: config/studies/demo.yaml)")
    p.add_argument("--robot", metavar="mock|desktop|URL",
                   help="'mock' (the stand-in, in-process), 'desktop' (the laptop plays the robot; needs espeak-ng, an "
                        "OS package, and a sound device, else each sound is written as a WAV file; answer "
                        "with --input keyboard), tcp://IP:9559 (NAOqi <= 2.8) or tcps://IP:9503 "
                        "(NAOqi 2.9; login from NAO_USER/NAO_PASSWORD)")
    p.add_argument("--input", choices=INPUTS, help="where answers come from")
    p.add_argument("--turns", type=int, metavar="N", help="number of turns")
    p.add_argument("--speed", type=float, metavar="X", help="speed-up factor for everything spoken or waited")
    p.add_argument("--seed", type=int, metavar="S", help="random seed (recorded in session.json)")
    p.add_argument("--out", metavar="DIR", help="folder under which the session folder is created")
    p.add_argument("--pseudonym", metavar="ID", help="participant pseudonym (names the session folder)")
    p.add_argument("--eeg", choices=EEG_MODES, help="EEG: off, the device's simulation, or the live headband (lsl)")
    p.add_argument("--task", metavar="NAME", help="the task trained: sequence | nback | an installed plug-in's "
                   "(task.name; nao-trainer plugins lists them)")
    p.add_argument("--robot-model", metavar="NAME",
                   help="robot model plug-in: nao, pepper (overrides robot.model; nao-trainer plugins lists them)")
    p.add_argument("--eeg-device", metavar="NAME",
                   help="EEG device plug-in (eeg.device): muse (muselsl / simulated Muse), brainflow (a BrainFlow "
                        "board, its synthetic board when simulated); nao-trainer plugins lists them")
    p.add_argument("--allow-simulated-eeg", action="store_true",
                   help="pilots only: a session where a person answers or a real robot plays may take a simulated or "
                        "replayed stream (simulate-muse), refused otherwise with exit 4 (eeg.allow_simulated)")
    p.add_argument("--eeg-source-id", metavar="ID",
                   help="use only the LSL stream with this source_id (one headband among several; eeg.source_id)")
    p.add_argument("--user-model", metavar="CLUSTER|FILE",
                   help="simulated participant from a fitted user model (cluster id or simulator JSON)")
    p.add_argument("--policy", metavar="SPEC",
                   help="schedule | random | usp:CLUSTER[:METHOD] | personalised (assess, match the user models, "
                        "choose by posterior expected value, keep learning; docs/explanation/personalisation.md) | bayes (the "
                        "exact Bayes-adaptive planner, policy.objective)")
    p.add_argument("--prior", metavar="clusters|psychometric|PATH",
                   help="the bayes policy's prior (policy.prior): the fitted clusters, the pooled psychometric model, "
                        "a psychometric prior file or a folder of user simulators; default: psychometric under "
                        "policy.objective target-p:R or target-rate:R, clusters under score")
    p.add_argument("--no-learning", action="store_true", help="a learning policy does not update during the session")
    p.add_argument("--no-practice", action="store_true", help="skip the practice round")
    p.add_argument("--quiet", action="store_true", help="no per-turn progress lines")
    p.add_argument("--plot", action="store_true", help="also draw session.png (levels, score, engagement) in the session folder")
    p.add_argument("--max-duration", type=float, metavar="S",
                   help="end the session cleanly between turns after S session seconds (session.max_duration_s)")
    p.add_argument("--resume", metavar="SESSION_DIR",
                   help="continue an interrupted session in its folder (its configuration, seed and learning state)")
    p.add_argument("--fresh-policy", action="store_true",
                   help="start a learning policy from the trained one, not from the participant's saved state "
                        "(the old state is moved aside); personalised: start from the prior")
    p.add_argument("--no-keys", action="store_true", help="do not read operator keys (p pause, r resume, s stop) from the terminal")
    p.add_argument("--console", action="store_true", help="serve the supervisor console (a web page; the link is printed)")
    p.add_argument("--console-port", type=int, metavar="P", help="console port (default: console.port, 0 = a free port)")
    p.add_argument("--console-bind", metavar="ADDRESS",
                   help="listen on ADDRESS instead of 127.0.0.1 (prints a warning: others could steer the session); "
                        "beyond loopback the console is served over HTTPS with a self-signed certificate")
    p.add_argument("--console-insecure", action="store_true",
                   help="with --console-bind beyond loopback: plain HTTP (the token crosses the network in clear)")
    p.add_argument("--console-tls", action="store_true", help="serve the console over HTTPS even on loopback")
    p.set_defaults(func=run)


def overrides_from_args(args: argparse.Namespace) -> dict[str, object]:
    """Command-line flags as dotted configuration keys (None = not given)."""
    return {
        "robot.url": args.robot,
        "answers.input": args.input,
        "session.turns": args.turns,
        "timing.speed": args.speed,
        "session.seed": args.seed,
        "session.output": str(Path(args.out).resolve()) if args.out else None,
        "participant.pseudonym": args.pseudonym,
        "eeg.mode": args.eeg,
        "eeg.device": args.eeg_device,
        "robot.model": args.robot_model,
        "task.name": args.task,
        "eeg.source_id": args.eeg_source_id,
        "eeg.allow_simulated": True if args.allow_simulated_eeg else None,
        "policy.kind": args.policy,
        "policy.prior": args.prior,
        "participant_model.user_model": args.user_model,
        "policy.learning": False if args.no_learning else None,
        "session.practice": False if args.no_practice else None,
        "session.max_duration_s": args.max_duration,
    }


def run(args: argparse.Namespace) -> int:
    # Heavy (numpy, transitions, the adapters): imported when a session runs, so `nao-trainer --help` stays fast.
    from nao_trainer.session.resume import prepare_resume
    from nao_trainer.session.wiring import RunOptions, run_session

    overrides = overrides_from_args(args)
    if args.console_port is not None and not 0 <= args.console_port <= 65535:
        raise ConfigError(f"--console-port {args.console_port}: a port is 0-65535 (0 = any free port)")
    options = RunOptions(quiet=args.quiet, keys=not args.no_keys, console=args.console or args.console_port is not None,
                         console_port=args.console_port, console_bind=args.console_bind,
                         console_insecure=args.console_insecure, console_tls=args.console_tls,
                         fresh_policy=args.fresh_policy)
    resume = None
    if args.resume:
        given = [k for k, v in overrides.items() if v is not None] + (["--config"] if args.config else []) \
            + (["--fresh-policy"] if args.fresh_policy else [])
        if given:
            raise ConfigError(f"--resume continues a session with its own configuration; drop {', '.join(given)}")
        _refuse_study_folder(Path(args.resume), "--resume", resume=True)
        config, resume = prepare_resume(Path(args.resume))
        print(f"resuming {resume.folder} after turn {resume.checkpoint['completed']} of {config.session.turns}",
              file=sys.stderr)
    else:
        if args.config is None and args.robot is not None and is_robot_address(args.robot):
            # The demo study is a simulation (sped up, simulated participant and Muse, pseudonym "demo"):
            # a robot must never run with it by accident.
            raise ConfigError(f"--robot {redact_url(args.robot)} needs --config FILE: without it the demo study would run "
                              "(speed x25, simulated participant and EEG, pseudonym 'demo'); use --config "
                              "config/studies/paper-2018.yaml or your own study file")
        config = load_config(args.config, overrides)
        _refuse_study_folder(config.session.output_dir, "session.output")
    result = run_session(config, options, resume=resume)
    print(result.summary())
    if args.plot and result.path is not None and result.completed_rows:
        from nao_trainer.plots.session import plot_session

        print(f"plot: {plot_session(result.path)}")
    return result.exit_code


def _refuse_study_folder(path: Path, what: str, resume: bool = False) -> None:
    """A study participant's sessions run through ``study next`` (arm, number, blinding, registry), never a bare run."""
    from nao_trainer.study.registry import study_holding

    root = study_holding(path)
    if root is None:
        return
    how = f"`nao-trainer study next {root} PSEUDONYM --resume`" if resume else \
        f"`nao-trainer study next {root} PSEUDONYM` (give another --out for a session outside the study)"
    raise ConfigError(f"{what} {path}: inside the study folder {root}; a study participant's session runs with {how}")
