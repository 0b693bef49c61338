"""`nao-trainer mock-robot`: serve the NAO stand-in over qi until Ctrl-C / SIGTERM."""
from __future__ import annotations

import argparse
import sys

from nao_trainer.errors import ConfigError


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
        help="address to serve on, tcp://HOST:PORT, or tcps://HOST:PORT (NAOqi 2.9: TLS and a login checked "
             "against NAO_USER / NAO_PASSWORD); port 0 picks a free one; default %(default)s",
    )
    p.add_argument("--latency-ms", type=float, default=0.0, metavar="MS",
                   help="network round trip added to every call (default 0)")
    p.add_argument("--beep-latency-ms", type=float, default=0.0, metavar="MS",
                   help="audio latency before each playSine tone starts (robot time; default 0)")
    p.add_argument("--freeze-s", type=float, default=10.0, metavar="S",
                   help="how long SIGUSR1 freezes the link (alive but silent, like a dropped Wi-Fi; default 10)")
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
    from nao_trainer.robot.address import credentials_from_env
    from nao_trainer.robot.standin import Login, serve  # imports qi: keep `nao-trainer --help` fast

    login = None
    if args.listen.strip().lower().startswith("tcps://"):
        creds = credentials_from_env()
        if creds is None:
            raise ConfigError("mock-robot --listen tcps://...: set NAO_USER and NAO_PASSWORD, the login it accepts")
        login = Login(creds.user, creds.password)
    return serve(args.listen, speed=args.speed, transcript_path=args.transcript, allow_remote=args.allow_remote,
                 echo=sys.stderr if args.echo else None, login=login, latency_s=args.latency_ms / 1000,
                 beep_latency_s=args.beep_latency_ms / 1000, freeze_s=args.freeze_s)
