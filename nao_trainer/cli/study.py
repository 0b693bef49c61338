"""`nao-trainer study`: a controlled study (init, enrol, next, status, withdraw, amend, analyse, power, export)
and, as before, `nao-trainer study STUDY_DIR`: one row per session (CSV) and a figure comparing the participants."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from nao_trainer.cli._filters import add_filter_args, filter_from_args
from nao_trainer.eeg.settings import MODES as EEG_MODES
from nao_trainer.errors import ConfigError, DataError
from nao_trainer.files import read_text, write_text_atomic
from nao_trainer.session.config import INPUTS
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.seal import key_path
from nao_trainer.study import remote

ACTIONS = ("init", "site", "statistician", "enrol", "withdraw", "amend", "status", "next", "record", "repair",
           "unblind", "analyse", "power", "export", "table")
DESCRIPTION = """\
A controlled study (docs/how-to/study.md), in order:
  study init PROTOCOL --out STUDY_DIR        freeze the protocol, draw the concealed allocation
  study power PROTOCOL [--n 10,20,40]        simulated power of the pre-registered test per N
  study enrol STUDY_DIR --consent-date D --consent-version V    the next pseudonym and its arm
  study next STUDY_DIR PSEUDONYM [run flags] that participant's next session
  study status STUDY_DIR                     enrolment, sessions, overdue, withdrawals, data quality
  study withdraw STUDY_DIR PSEUDONYM --data keep|delete
  study amend STUDY_DIR PROTOCOL --reason R [--change-arms]   a recorded change of the frozen protocol
  study repair STUDY_DIR                     record killed sessions and session folders the registry lacks
  study record STUDY_DIR                     PostgreSQL: this laptop's sessions the server did not take yet
  study unblind STUDY_DIR --reason R         the statistician: the arms, the unblinding recorded
  study analyse STUDY_DIR                    the protocol's mixed model, estimates, figures
  study export STUDY_DIR --bids OUT | --published OUT
And the session table: study STUDY_DIR [--out DIR] [--no-figure] (also `study table STUDY_DIR`):
study.csv (session, pseudonym, study, input, date, turns, score, success per level, mean engagement, turns with EEG,
policy, status, duration) and study.png. Sessions that cannot be read are reported one line each and left out."""


def register(sub) -> None:
    p = sub.add_parser("study", help=f"a controlled study ({', '.join(a for a in ACTIONS if a != 'table')}) "
                                     "or the table of the sessions under STUDY_DIR",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", "-o", type=Path, default=None, metavar="DIR", help=argparse.SUPPRESS)
    p.add_argument("--no-figure", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("words", nargs=argparse.REMAINDER, metavar="ACTION|STUDY_DIR ...",
                   help=f"one of {', '.join(ACTIONS)} and its arguments, or a folder of sessions")
    p.set_defaults(func=run)


def actions_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="nao-trainer study", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("table", help="one row per session written by `run` (CSV + figure)")
    p.add_argument("root", metavar="STUDY_DIR", type=Path, help="folder holding session folders (session.output)")
    p.add_argument("--out", "-o", type=Path, default=None, metavar="DIR",
                   help="where study.csv and study.png go (default: STUDY_DIR)")
    p.add_argument("--no-figure", action="store_true", help="only the CSV")
    add_filter_args(p)
    p = sub.add_parser("init", help="freeze a protocol in a new study folder and draw the allocation")
    p.add_argument("protocol", type=Path, metavar="PROTOCOL")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="STUDY_DIR")
    p.add_argument("--allocation-seed-file", type=Path, metavar="FILE",
                   help="a seed supplied by a third party (default: drawn from the operating system's entropy)")
    p.add_argument("--registry", default=None, metavar="postgresql://HOST/DB",
                   help="the registry on a PostgreSQL server (several sites; docs/how-to/multi-site-study.md); "
                        "no password in the URL")
    p.add_argument("--stratify-by-site", action="store_true", help="with --registry: one sequence per site")
    p = sub.add_parser("site", help="PostgreSQL registry: add a site (its own role, password and pseudonym range)")
    p.add_argument("what", choices=("add",))
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("name", metavar="NAME")
    p = sub.add_parser("statistician", help="PostgreSQL registry: a login role that may unblind (logged)")
    p.add_argument("what", choices=("add",))
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("name", metavar="LOGIN")
    p = sub.add_parser("enrol", help="enrol the next participant: pseudonym and arm")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("--consent-date", required=True, metavar="YYYY-MM-DD")
    p.add_argument("--consent-version", required=True, metavar="V")
    p.add_argument("--stratum", action="append", default=[], metavar="NAME=LEVEL",
                   help="the participant's level of a stratum of the protocol (repeat per stratum)")
    p = sub.add_parser("withdraw", help="record a participant's withdrawal and what happens to the data")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("pseudonym", metavar="PSEUDONYM")
    p.add_argument("--data", required=True, choices=("keep", "delete"))
    p.add_argument("--reason", default="", help="optional; never personal details")
    p = sub.add_parser("amend", help="replace the frozen protocol, recorded with time, reason and hash")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("protocol", type=Path, metavar="PROTOCOL")
    p.add_argument("--reason", required=True)
    p.add_argument("--change-arms", action="store_true",
                   help="allow a change of what an enrolled arm does, or blinding turned off (recorded, reported)")
    p = sub.add_parser("repair", help="record sessions on disk the registry does not know, and killed ones")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p = sub.add_parser("record", help="a site's laptop (PostgreSQL registry): record the sessions kept in "
                                      "STUDY_DIR/outbox (the network went during them, or they were killed)")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p = sub.add_parser("unblind", help="the statistician: reveal the arms (recorded with time, who and reason)")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("--reason", required=True)
    p.add_argument("--who", default=None, help="who unblinds (default: user@host)")
    p = sub.add_parser("status", help="enrolment, sessions per arm, overdue, withdrawals, data quality")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p = sub.add_parser("next", help="run a participant's next session (run flags pass through)")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("pseudonym", metavar="PSEUDONYM")
    p.add_argument("--resume", action="store_true",
                   help="continue the participant's interrupted last session (its folder, seed and learning state)")
    _run_flags(p)
    p = sub.add_parser("analyse", help="the protocol's mixed model: estimates, 95 %% CIs, figures")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("--out", "-o", type=Path, default=None, metavar="DIR", help="default: STUDY_DIR/analysis")
    p = sub.add_parser("power", help="simulated power of the pre-registered test per number of participants")
    p.add_argument("protocol", type=Path, metavar="PROTOCOL")
    p.add_argument("--n", default="12,24,48,96", metavar="N1,N2,...", help="numbers of participants")
    p.add_argument("--reps", type=int, default=200, metavar="R", help="simulated studies per N")
    p.add_argument("--seed", type=int, default=1, metavar="S")
    p.add_argument("--users", default=None, choices=("sessions", "clusters", "level-only", "task"),
                   help="simulated participants: one per real session (held out, needs --data; the default), the "
                        "clusters, or the protocol's task's own (task: the default for a task the published data "
                        "are not of, e.g. nback)")
    p.add_argument("--data", type=Path, metavar="ROOT", help="the published dataset root (for --users sessions)")
    p.add_argument("--drift", type=float, default=0.3, metavar="SD",
                   help="session-to-session change of ability (logit SD; default 0.3)")
    p.add_argument("--out", "-o", type=Path, default=Path("power"), metavar="DIR")
    p = sub.add_parser("export", help="BIDS-EEG (--bids) or the published dataset's layout (--published)")
    p.add_argument("root", type=Path, metavar="STUDY_DIR")
    p.add_argument("--bids", type=Path, metavar="OUT")
    p.add_argument("--published", type=Path, metavar="OUT")
    return parser


def _run_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", metavar="mock|desktop|URL")
    p.add_argument("--input", choices=INPUTS)
    p.add_argument("--eeg", choices=EEG_MODES)
    p.add_argument("--eeg-device", metavar="NAME")
    p.add_argument("--eeg-source-id", metavar="ID")
    p.add_argument("--speed", type=float, metavar="X")
    p.add_argument("--turns", type=int, metavar="N")
    p.add_argument("--user-model", metavar="CLUSTER|FILE", help="a simulated participant (pilots and tests)")
    p.add_argument("--no-practice", action="store_true")
    p.add_argument("--max-duration", type=float, metavar="S")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--no-keys", action="store_true")
    p.add_argument("--console", action="store_true")
    p.add_argument("--console-port", type=int, metavar="P")
    p.add_argument("--console-bind", metavar="ADDRESS")


def run(args: argparse.Namespace) -> int:
    words = list(args.words)
    if not words:
        actions_parser().print_help()
        return 2
    if words[0] not in ACTIONS:  # `nao-trainer study STUDY_DIR [--out DIR] [--no-figure]`, as before
        words = ["table", *words] + (["--out", str(args.out)] if args.out else []) \
            + (["--no-figure"] if args.no_figure else [])
    sub = actions_parser().parse_args(words)
    root = getattr(sub, "root", None)
    return int(globals()[f"_{sub.action}"](sub) or 0)


def _statistician(args: argparse.Namespace) -> int:
    if not remote.is_remote(args.root):
        raise ConfigError(f"{args.root}: roles need a registry on PostgreSQL (study init --registry postgresql://...)")
    with remote.connect(args.root) as conn:
        role, password = remote.pg.statistician_add(conn, args.name)
    print(f"statistician: role {role}; password (shown once, stored nowhere by nao-trainer): {password}")
    return 0


def _site(args: argparse.Namespace) -> int:
    if not remote.is_remote(args.root):
        raise ConfigError(f"{args.root}: sites need a registry on PostgreSQL (study init --registry postgresql://...)")
    role, password = remote.site_add(args.root, args.name)
    print(f"site {args.name}: role {role}; password (shown once, stored nowhere by nao-trainer; give it to the "
          f"site for its PGPASSFILE): {password}")
    return 0


def _table(args: argparse.Namespace) -> int:
    from nao_trainer.data.study import read_study
    from nao_trainer.learn.psychometric_prior import load_prior

    out = args.out or args.root
    try:
        prior, span_note = load_prior(), []
    except DataError as exc:  # the table is still worth having: its span columns stay empty, and it says why
        prior, span_note = None, [f"span columns left empty: {exc}"]
    study = read_study(args.root, filter_from_args(args), prior)
    for line in study.problems + study.notes + span_note:
        print(f"nao-trainer study: {line}", file=sys.stderr)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "study.csv", study.to_csv())
    except OSError as exc:
        raise DataError(f"{out}: cannot write the study table ({exc.strerror}); give another --out") from None
    inputs: dict[str, int] = {}
    for s in study.sessions:
        inputs[s.row["input"]] = inputs.get(s.row["input"], 0) + 1
    kinds = ", ".join(f"{n} {k}" for k, n in sorted(inputs.items()))
    print(f"{out / 'study.csv'}: {len(study.sessions)} sessions ({kinds})", file=sys.stderr)
    if not args.no_figure:
        from nao_trainer.plots.study import plot_study

        print(f"{plot_study(study, out / 'study.png')}: figure saved", file=sys.stderr)
    return 0


def _init(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import init_study

    seed = None
    if args.allocation_seed_file is not None:
        text = read_text(args.allocation_seed_file, ConfigError, fix="give the file the third party supplied")
        try:
            seed = int(text.strip(), 0)
        except ValueError:
            raise ConfigError(f"{args.allocation_seed_file}: not a whole number; the file holds the seed only") from None
    if args.registry is not None:
        if seed is not None and args.stratify_by_site:
            raise ConfigError("--allocation-seed-file with --stratify-by-site: each site's sequence is drawn when the "
                              "site is added, from the operating system's entropy; give one or the other")
        made = remote.init(args.protocol, args.out, args.registry, args.stratify_by_site, seed)
        print(f"{args.out}: study {made['protocol'].name} initialised on {remote.pg.redact(args.registry)} (roles "
              f"{made['prefix']}_operator, {made['prefix']}_statistician; add sites with `nao-trainer study site add "
              f"{args.out} NAME`); the allocation is readable by no operator role")
        return 0
    if args.stratify_by_site:
        raise ConfigError("--stratify-by-site: only with --registry postgresql://...")

    from nao_trainer.study.registry import BACKUP, REGISTRY_FILE, block_sizes

    migrating = (args.out / REGISTRY_FILE).is_file()
    study = init_study(args.protocol, args.out, seed)
    p = study.protocol
    if migrating:
        print(f"{args.out}: JSON study migrated to the database ({len(study.participants)} participants; the JSON "
              f"files are kept in {args.out / BACKUP}); key {key_path(study.registry['study_id'])}")
        return 0
    if p.allocation.seed is not None:
        print(f"study init: allocation.seed in {args.protocol} is not used: the allocation is drawn from the "
              "operating system's entropy (a seed anyone can read would reveal it)", file=sys.stderr)
    sizes = " or ".join(map(str, block_sizes(p)))
    print(f"{args.out}: study {p.name} initialised (protocol sha256 {p.sha256}; {len(p.arms)} arms, target "
          f"{p.target_n}, blocks of {sizes}, each size drawn by chance); the allocation is sealed with the study key "
          f"{key_path(study.registry['study_id'])} (outside the study folder: back it up, and give it to no "
          "operator)")
    return 0


def _enrol(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import enrol, open_study

    strata = {}
    for item in args.stratum:
        name, sep, level = item.partition("=")
        if not sep:
            raise ConfigError(f"--stratum {item!r}: write NAME=LEVEL")
        strata[name] = level

    if remote.is_remote(args.root):
        pseudonym = remote.enrol(args.root, args.consent_date, args.consent_version, strata)
        print(f"{pseudonym}: enrolled (arm concealed: this role cannot read it; consent {args.consent_date} version "
              f"{args.consent_version})")
        return 0
    entry = enrol(args.root, args.consent_date, args.consent_version, strata)
    study = open_study(args.root)
    blinded = study.protocol.blinding and not study.unblinded
    arm = "arm concealed from the operator, blinding on" if blinded else f"arm {study.arm_of(entry['pseudonym'])}"
    print(f"{entry['pseudonym']}: enrolled ({arm}; consent {entry['consent_date']} version "
          f"{entry['consent_version']}). Run the sessions with: nao-trainer study next {args.root} {entry['pseudonym']}")
    return 0


def _withdraw(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import open_study, withdraw
    from nao_trainer.study.runner import repair

    if remote.is_remote(args.root):
        _entry, deleted = remote.withdraw(args.root, args.pseudonym, args.data, args.reason)
        print(f"{args.pseudonym}: withdrawal recorded in the registry (data {args.data}"
              + (f"; {len(deleted)} folder(s) deleted on this laptop: delete the statistician's copies too)"
                 if args.data == "delete" else ")"))
        return 0
    if not open_study(args.root).participant(args.pseudonym)["withdrawn"]:
        repair(args.root, args.pseudonym)  # a killed session of this participant is on record first
    _entry, deleted = withdraw(args.root, args.pseudonym, args.data, args.reason)
    sessions = [f for f in deleted if f.parent.name == "sessions" and f.name.startswith(f"{args.pseudonym}_")]
    state = len(deleted) - len(sessions)
    print(f"{args.pseudonym}: withdrawal recorded (data {args.data}" +
          (f"; {len(sessions)} session folder(s){' and the learning state' if state else ''} deleted)"
           if args.data == "delete" else ")"))
    return 0


def _amend(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import amend

    go = remote.amend if remote.is_remote(args.root) else amend
    entry = go(args.root, args.protocol, args.reason, args.change_arms)
    changes = f"; CHANGES ARMS: {'; '.join(entry['changes'])}" if entry["changes"] else ""
    print(f"{args.root}: amendment recorded {entry['time']}: {entry['old_sha256'][:12]} -> {entry['new_sha256'][:12]} "
          f"({entry['reason']}){changes}; study configuration {entry['study_config']}")
    return 0


def _status(args: argparse.Namespace) -> int:
    from nao_trainer.study.progress import study_status
    from nao_trainer.study.registry import open_study

    if remote.is_remote(args.root):
        print("\n".join(remote.status_lines(args.root)))
        return 0
    print("\n".join(study_status(open_study(args.root)).lines))
    return 0


def _next(args: argparse.Namespace) -> int:
    from nao_trainer.session.wiring import RunOptions
    from nao_trainer.study.runner import run_next

    if args.console_port is not None and not 0 <= args.console_port <= 65535:
        raise ConfigError(f"--console-port {args.console_port}: a port is 0-65535 (0 = any free port)")
    flags = {"robot.url": args.robot, "answers.input": args.input, "eeg.mode": args.eeg, "eeg.device": args.eeg_device,
             "eeg.source_id": args.eeg_source_id, "timing.speed": args.speed, "session.turns": args.turns,
             "participant_model.user_model": args.user_model, "session.practice": False if args.no_practice else None,
             "session.max_duration_s": args.max_duration}
    options = RunOptions(quiet=args.quiet, keys=not args.no_keys, console=args.console or args.console_port is not None,
                         console_port=args.console_port, console_bind=args.console_bind)

    go = remote.run_next if remote.is_remote(args.root) else run_next
    _plan, result = go(args.root, args.pseudonym, flags, options, resume=args.resume)
    print(result.summary())
    return result.exit_code


def _analyse(args: argparse.Namespace) -> int:
    from nao_trainer.study.analysis import analyse
    from nao_trainer.study.registry import open_study

    study = remote.statistician_study(args.root, "study analyse") if remote.is_remote(args.root) else \
        open_study(args.root, reveal=True)
    out = args.out or args.root / "analysis"
    report = analyse(study, out)
    print(report.text)
    for a in study.registry["amendments"]:
        if a.get("changes"):
            print(f"NOTE: amendment {a['time']} changed what arms do after {a['enrolled_at_amendment']} enrolment(s) "
                  f"({'; '.join(a['changes'])}): sessions before and after it are pooled above")
    from nao_trainer.plots.trial import plot_outcomes

    for outcome in report.outcomes:
        print(f"{plot_outcomes(report, outcome, out / f'{outcome}.png')}: figure saved", file=sys.stderr)
    return 0


def _power(args: argparse.Namespace) -> int:
    from nao_trainer.study.power import power_study
    from nao_trainer.tasks.base import published

    try:
        ns = sorted({int(x) for x in args.n.split(",") if x.strip()})
    except ValueError:
        raise ConfigError(f"--n {args.n!r}: give whole numbers separated by commas, e.g. 12,24,48") from None
    if not ns or ns[0] < 2 or args.reps < 2:
        raise ConfigError("--n needs numbers >= 2 and --reps >= 2")
    if not 0 <= args.drift <= 3:
        raise ConfigError(f"--drift {args.drift}: give a logit SD between 0 and 3")
    protocol = load_protocol(args.protocol)
    task, engagement = _protocol_task(protocol)
    ours = published(task)  # the fitted user sets and the dataset are people playing this task
    args.users = args.users or ("sessions" if ours else "task")
    if args.users != "task" and not ours:
        raise ConfigError(f"study power --users {args.users}: the fitted user sets and the dataset are people playing "
                          f"the sequence task; protocol {protocol.name!r} trains task {task.name!r}, simulated on its "
                          "own simulated users (--users task, its default)")
    if args.users == "sessions" and args.data is None:
        raise ConfigError("study power --users sessions needs the published dataset: add --data ROOT (its extracted "
                          "clean_data folder), or give --users clusters")
    if args.data is not None and args.data.is_dir() and any(args.data.glob("*.tar.xz")) \
            and not any(args.data.glob("*/session_*")):
        raise ConfigError(f"--data {args.data}: holds the dataset's archives, not its sessions; extract one first "
                          "(README, 'Results on the published data') and give the extracted clean_data folder")
    from nao_trainer.learn.users import load_users

    print(f"study power: loading the {args.users} users ...", file=sys.stderr, flush=True)
    if args.users == "task":
        from nao_trainer.learn.users import task_user_set

        name, users = f"task {task.name}", task_user_set(task, engagement)  # DataError in one line: none declared
    else:
        name, users = load_users(args.users, data=args.data, seed=args.seed)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{args.out}: cannot create ({exc.strerror}); give another --out") from None
    report = power_study(protocol, ns, args.reps, args.seed, users, name, args.drift, progress=sys.stderr)
    if args.users == "task":
        report.notes.append(f"users: task {task.name}'s own simulated users (Task.simulated_users), not fitted to "
                            "people; their engagement is the study's participant_model.engagement_by_level")
    report.write(args.out)
    print(report.text())
    from nao_trainer.plots.trial import plot_power

    print(f"{plot_power(report, args.out / 'power.png')}: figure saved", file=sys.stderr)
    return 0


def _protocol_task(protocol: Any) -> tuple[Any, Any]:
    """(the task the protocol's arms train, the study's engagement by level); one line when the arms' tasks differ."""
    configs = [protocol.arm_config(arm) for arm in protocol.arms]
    names = sorted({c.task.name for c in configs})
    if len(names) > 1:
        raise ConfigError(f"study power: protocol {protocol.name!r}: its arms train different tasks ({', '.join(names)}); "
                          "a power analysis simulates one task")
    return configs[0].task.build_task(), configs[0].participant_model.engagement_by_level


def _export(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import open_study

    if (args.bids is None) == (args.published is None):
        raise ConfigError("study export: give --bids OUT or --published OUT")

    study = remote.statistician_study(args.root, "study export") if remote.is_remote(args.root) else \
        open_study(args.root, reveal=True)
    if args.bids is not None:
        from nao_trainer.study.bids import export_bids

        summary = export_bids(study, args.bids)
    else:
        from nao_trainer.study.published import export_published

        summary = export_published(study, args.published)
    print(summary)
    return 0


def _record(args: argparse.Namespace) -> int:
    if not remote.is_remote(args.root):
        return _repair(args)  # one laptop: what repair records
    found = remote.record(args.root, sys.stdout)
    print(f"{args.root}: {len(found)} session(s) recorded from {args.root / remote.OUTBOX}")
    return 0


def _repair(args: argparse.Namespace) -> int:
    from nao_trainer.study.runner import repair

    if remote.is_remote(args.root):  # a site's laptop: its outbox (killed sessions, and those the network lost)
        return _record(args)
    found = repair(args.root)
    for e in found:
        print(f"{e['pseudonym']} session {e['number']}: {e['folder'] or 'no folder'} recorded as {e['status']}")
    print(f"{args.root}: {len(found)} session(s) recorded")
    return 0


def _unblind(args: argparse.Namespace) -> int:
    from nao_trainer.study.registry import unblind

    pairs = remote.unblind(args.root, args.reason) if remote.is_remote(args.root) else \
        unblind(args.root, args.reason, args.who)
    print(f"{args.root}: unblinding recorded ({args.reason}); {len(pairs)} participant(s)")
    for pseudonym, arm in pairs:
        print(f"{pseudonym}\t{arm}")
    return 0
