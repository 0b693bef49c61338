"""`nao-trainer run`: play one training session (by default the demo study against the stand-in)."""
from __future__ import annotations

import argparse
from pathlib import Path

from nao_trainer.eeg.settings import MODES as EEG_MODES
from nao_trainer.session.config import INPUTS


def register(sub) -> None:
    p = sub.add_parser(
        "run",
        help="play a training session (no flags: the demo study against the NAO stand-in)",
        description="Play one training session. With no flags: the demo study (config/studies/demo.yaml), "
                    "the NAO stand-in started in this process, a simulated participant, 25 sped-up turns. "
                    "Flags override the study configuration.",
    )
    p.add_argument("--config", metavar="FILE", help="study configuration (default: config/studies/demo.yaml)")
    p.add_argument("--robot", metavar="mock|URL",
                   help="'mock' (the stand-in, in-process), tcp://IP:9559 (NAOqi <= 2.8) or tcps://IP:9503 "
                        "(NAOqi 2.9; login from NAO_USER/NAO_PASSWORD)")
    p.add_argument("--input", choices=INPUTS, help="where answers come from")
    p.add_argument("--turns", type=int, metavar="N", help="number of turns")
    p.add_argument("--speed", type=float, metavar="X", help="speed-up factor for everything spoken or waited")
    p.add_argument("--seed", type=int, metavar="S", help="random seed (recorded in session.json)")
    p.add_argument("--out", metavar="DIR", help="folder under which the session folder is created")
    p.add_argument("--pseudonym", metavar="ID", help="participant pseudonym (names the session folder)")
    p.add_argument("--eeg", choices=EEG_MODES, help="EEG: off, a simulated Muse, or a Muse over LSL")
    p.add_argument("--user-model", metavar="CLUSTER|FILE",
                   help="simulated participant from a fitted user model (cluster id or simulator JSON)")
    p.add_argument("--policy", metavar="SPEC",
                   help="schedule | random | usp:CLUSTER[:METHOD] | personalised (assess, match the user models, "
                        "choose by posterior expected value, keep learning; docs/personalisation.md)")
    p.add_argument("--fresh", action="store_true",
                   help="personalised: set the participant's saved state aside (kept, renamed) and start from the prior")
    p.add_argument("--no-learning", action="store_true", help="a learning policy does not update during the session")
    p.add_argument("--no-practice", action="store_true", help="skip the practice round")
    p.add_argument("--quiet", action="store_true", help="no per-turn progress lines")
    p.add_argument("--plot", action="store_true", help="also draw session.png (levels, score, engagement) in the session folder")
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
        "policy.kind": args.policy,
        "participant_model.user_model": args.user_model,
        "policy.learning": False if args.no_learning else None,
        "session.practice": False if args.no_practice else None,
        "policy.fresh": True if args.fresh else None,
    }


def run(args: argparse.Namespace) -> int:
    from nao_trainer.session.config import load_config
    from nao_trainer.session.wiring import RunOptions, run_session

    config = load_config(args.config, overrides_from_args(args))
    result = run_session(config, RunOptions(quiet=args.quiet))
    print(result.summary())
    if args.plot and result.path is not None and result.completed_rows:
        from nao_trainer.plots.session import plot_session

        print(f"plot: {plot_session(result.path)}")
    return result.exit_code
