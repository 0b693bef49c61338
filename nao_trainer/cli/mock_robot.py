"""`nao-trainer mock-robot`: serve the NAO stand-in over qi until Ctrl-C / SIGTERM."""
from __future__ import annotations

import argparse
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "mock-robot",
        help="serve a NAO stand-in over qi (no robot needed)",
        description=(
            "Serve a NAO stand-in over a real qi session: ALTextToSpeech, ALAnimatedSpeech, ALAudioPlayer, "
            "ALLeds, ALRobotPosture, ALMotion, ALMemory (head buttons) and the NaoTrainerStandIn control "
            "service. Point `nao-trainer run --robot URL` at the printed address."
        ),
    )
    p.add_argument(
        "--listen",
        default="tcp://127.0.0.1:9559",
        metavar="URL",
        help="address to serve on, tcp://HOST:PORT (port 0 picks a free one; default %(default)s)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="time factor: 10 speaks ten times faster (default 1)")
    p.add_argument("--transcript", metavar="FILE", help="append every call as a JSON line to FILE")
    p.add_argument("--echo", action="store_true", help="print each call the robot receives on stderr")
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow a non-loopback --listen address (serves other machines on the network)",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from nao_trainer.robot.standin import serve  # imports qi: keep `nao-trainer --help` fast

    return serve(args.listen, speed=args.speed, transcript_path=args.transcript, allow_remote=args.allow_remote,
                 echo=sys.stderr if args.echo else None)
