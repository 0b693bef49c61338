"""Command line: a thin layer that parses arguments and calls library functions.

Each subcommand lives in its own module exposing ``register(subparsers)``; the parser's
``func(args) -> int`` does the work. User errors end as one line on stderr, never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
import threading

from nao_trainer import __version__
from nao_trainer.errors import DataError, Interrupted, UserError, note_interrupt
from nao_trainer.files import DISK_ERRNOS, cannot_write

#: Subcommand modules, in the order ``--help`` lists them.
COMMANDS = ("run", "check", "hardware_check", "mock_robot", "simulate_muse", "engagement", "import_data", "fit",
            "train", "evaluate", "sweep", "study", "plugins")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nao-trainer",
        description="Personalised robot-assisted cognitive training with a NAO and a Muse.",
    )
    parser.add_argument("--version", action="version", version=f"nao-trainer {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f".{name}", __name__).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:  # no command: say what there is (the demo is `nao-trainer run`)
        parser.print_help()
        return 0
    args, extra = parser.parse_known_args(argv)
    if extra:  # `run --polcy bayes`: the command's own usage, not the top-level one
        _command_parser(parser, getattr(args, "command", None)).error(f"unrecognized arguments: {' '.join(extra)}")
    args.argv = argv  # what was parsed (recorded by commands that log their command line), not sys.argv
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with _ctrl_c_noted():
            return int(args.func(args) or 0)
    except UserError as exc:
        message = str(exc).replace("\r", "\\r").replace("\n", "\\n")  # always one line, whatever was echoed
        print(f"nao-trainer {args.command}: error: {message}", file=sys.stderr)
        return exc.exit_code
    except (KeyboardInterrupt, Interrupted):
        print(f"nao-trainer {args.command}: interrupted", file=sys.stderr)
        return Interrupted.exit_code
    except BrokenPipeError:  # the reader went away (`nao-trainer study status DIR | head`): nothing to say to it
        _quiet_stdout()
        return 0
    except OSError as exc:  # a write the command did not catch itself failed: a full disk or a file size limit
        if exc.errno not in DISK_ERRNOS:
            raise
        out = getattr(args, "out", None)
        message = cannot_write(out or "an output file", "an output file" if out and exc.filename is None else "", exc,
                               f"choose another output folder (--out) for {args.command}")
        print(f"nao-trainer {args.command}: error: {message}", file=sys.stderr)
        return DataError.exit_code


class _ctrl_c_noted:
    """Python's Ctrl-C handler, which also notes the Ctrl-C (``errors.raise_if_interrupted`` raises it again
    where a library swallowed the first KeyboardInterrupt); only where Python's own handler is in place."""

    def __enter__(self) -> None:
        self.previous = None
        note_interrupt(False)
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self.previous = signal.signal(signal.SIGINT, _on_ctrl_c)

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)


def _on_ctrl_c(signum: int, frame: object) -> None:
    note_interrupt()
    raise KeyboardInterrupt


def _command_parser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The subcommand's parser (its usage is what a mistyped flag of that command should show), else the top one."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush raises nothing more (Python's SIGPIPE note)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def entry_point() -> None:
    code = main()
    if "qi" in sys.modules:
        # Everything is closed and written by now. Interpreter teardown would let qi release the stand-in's
        # Python service objects on its own threads, which aborted about 2 % of exits (SIGABRT, "terminate
        # called without an active exception", in qi_python's shared-pointer release): leave without it.
        # Only where qi was loaded: other commands keep the teardown (it stops worker pools, for one).
        logging.shutdown()  # flush and close log files, as the skipped atexit would
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        except BrokenPipeError:
            pass
        os._exit(code)
    sys.exit(code)
