"""`nao-trainer mock-robot`: serve the NAO stand-in over qi until Ctrl-C / SIGTERM."""
from __future__ import annotations

import argparse
import sys

from nao_trainer import registry
from nao_trainer.errors import ConfigError
from nao_trainer.robot.address import credentials_from_env
from nao_trainer.robot.profile import load_profile


def register(sub) -> None:
    p = sub.add_parser(
        "mock-robot",
        help="serve a NAO stand-in over qi (no robot needed)",
        description=(
            "Serve a NAO stand-in over a real qi session: ALTextToSpeech, ALAnimatedSpeech, ALAudioPlayer, "
            "ALLeds, ALRobotPosture, ALMotion, ALMemory (head buttons) and the NaoTrainerStandIn control "
            "service. Point `nao-trainer run --robot URL` at the printed address. On a terminal, the keys a, b, "
            "c touch the front, middle and rear head buttons (hardware-check and --input tactile without a "
            "robot); from another shell: `nao-trainer mock-robot press A --robot URL`."
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
    p.add_argument("--no-keys", action="store_true", help="do not read head-button keys (a, b, c) from the terminal")
    p.add_argument("--profile", metavar="FILE", help="answer as the robot recorded in FILE does (`nao-trainer "
                   "hardware-check --record FILE`; config/robot-profiles/naoqi-2.8-docs.json: the NAOqi 2.8 docs)")
    p.add_argument("--model", default=registry.default("robot_model"), type=_model, metavar="MODEL",
                   help="the robot played: a robot model the stand-in has a body for "
                        "(nao, pepper; default %(default)s)")
    p.set_defaults(func=_run)
    actions = p.add_subparsers(dest="mock_action", metavar="ACTION")
    press = actions.add_parser("press", help="touch a head button of a running stand-in (from another shell)",
                               description="Touch a head button of a running `nao-trainer mock-robot`: A front, "
                                           "B middle, C rear, as a finger on a NAO does (0.1 s).")
    press.add_argument("button", type=str.upper, choices=("A", "B", "C"), metavar="A|B|C",
                       help="A front, B middle, C rear")
    press.add_argument("--robot", default="tcp://127.0.0.1:9559", metavar="URL",
                       help="the stand-in's address (its ready line prints it); default %(default)s")
    press.add_argument("--hold", type=float, default=None, metavar="S",
                       help="keep the hand on the button S seconds (robot time: 3 s puts NAO to sleep with "
                            "Autonomous Life on)")
    press.set_defaults(func=_press)


def _model(name: str) -> str:
    """``--model``: a robot model the stand-in can play (it says which; read when parsed, not for ``--help``)."""
    from nao_trainer.robot.standin.services import MODEL_POSTURES, can_play  # imports qi

    if not can_play(name):
        known = ", ".join(map(repr, MODEL_POSTURES))
        raise argparse.ArgumentTypeError(f"invalid choice: {name!r} (choose from {known})")
    return name


def _run(args: argparse.Namespace) -> int:
    from nao_trainer.robot.standin import Login, serve  # imports qi: keep `nao-trainer --help` fast

    login = None
    if args.listen.strip().lower().startswith("tcps://"):
        creds = credentials_from_env()
        if creds is None:
            raise ConfigError("mock-robot --listen tcps://...: set NAO_USER and NAO_PASSWORD, the login it accepts")
        login = Login(creds.user, creds.password)
    def keys(standin):  # a, b, c on this terminal touch the head buttons (none on a pipe: tests, services)
        from nao_trainer.robot.standin.keys import ButtonKeys

        reader = None if args.no_keys else ButtonKeys.start_if_terminal(standin.press, sys.stderr, sys.stdin.fileno())
        return reader.close if reader is not None else None

    return serve(args.listen, on_ready=keys, speed=args.speed, transcript_path=args.transcript, allow_remote=args.allow_remote,
                 echo=sys.stderr if args.echo else None, login=login, latency_s=args.latency_ms / 1000,
                 beep_latency_s=args.beep_latency_ms / 1000, freeze_s=args.freeze_s, model=args.model,
                 profile=_profile(args.profile))


def _profile(path: str | None):
    return None if path is None else load_profile(path)


def _press(args: argparse.Namespace) -> int:
    from nao_trainer.robot.standin import StandInClient  # imports qi

    if args.hold is not None and not 0 < args.hold <= 60:
        raise ConfigError(f"--hold must be between 0 and 60 seconds, got {args.hold:g}")
    names = {"A": "front", "B": "middle", "C": "rear"}
    with StandInClient.connect(args.robot) as client:
        if args.hold is None:
            key = client.press(args.button)
            print(f"pressed the {names[args.button]} head button ({args.button}, {key}) at {args.robot}")
        else:
            after = client.hold(args.button, args.hold)
            print(f"held the {names[args.button]} head button ({args.button}) {args.hold:g} s at {args.robot}: {after}")
    return 0
