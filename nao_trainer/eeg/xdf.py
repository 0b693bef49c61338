"""Record a session's EEG and marker streams to XDF with LabRecorder's engine (``labrecorder`` on PyPI).

XDF is the Lab Streaming Layer's file format: every stream with its LSL timestamps, its metadata
and the clock offsets measured while recording, readable by ``pyxdf``, MNE, EEGLAB and others.
No XDF writer lives here: LabRecorder's own engine writes the file.

The engine runs in a child process (``python -m nao_trainer.eeg.xdf``), for three reasons:

* its C++ side prints progress lines ("Opened the stream ...", "Wrote footer ...") on stdout and
  stderr: the child's output goes to the session's ``eeg/xdf.log``, never to the operator's terminal;
* it bundles its own liblsl, which reads only a config file: the child gets ``LSLAPICFG`` pointing
  at the project's scope (``lsl_scope.config_file``), so discovery stays on this machine;
* a killed session still leaves a complete file: the child stops when its stdin closes, which
  happens when the session ends for any reason, SIGKILL included; it then waits ``flush_s`` (the
  engine writes in chunks), stops the recording and writes every stream's footer. If the child
  itself is killed, the file is readable by pyxdf up to the last chunk written (tested); the
  monitor's CSV files stay the crash-safe record either way.
* the child never outlives the session: on Linux it asks the kernel for SIGTERM when its parent dies
  (``PR_SET_PDEATHSIG``; while it still looks for the streams SIGTERM ends it at once, while it
  records SIGTERM finishes the file), and :meth:`XdfRecorder.start` kills it when start-up itself is
  interrupted (SIGTERM, Ctrl-C). All of that needs the interpreter to run; a forked guard process
  (``start_guard``) kills the child outright when its session has been gone for longer than the
  stop limit, whatever the child is stuck in.

The child pins the streams by source_id. A marker pushed before the recorder's inlet connects is
not recorded: :meth:`XdfRecorder.start` returns once the marker outlet has a consumer.
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from nao_trainer.eeg.lsl_scope import config_file
from nao_trainer.errors import EEGUnavailable

INSTALL_HINT = "pip install 'nao-trainer[xdf]'"
#: ``prctl`` option: the signal a process gets when its parent dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1
#: Longest wait for the recording engine to write its footers and stop, once asked to (seconds). With its
#: streams gone (a killed session) liblsl's time-correction queries time out one by one: 5-20 s seen.
STOP_LIMIT_S = 60.0
#: The guard (``start_guard``) kills a recorder this long after the stop limit once its session is gone.
GUARD_EXTRA_S = 30.0
#: How long the child keeps recording after the stop request: the engine writes in chunks of ~0.5 s.
FLUSH_S = 1.0


def truncation(path: Path) -> str | None:
    """Why ``path`` is not a whole XDF file (cut by a full disk or a file size limit: the engine writes
    through a C++ stream that reports nothing), or None. Walks the chunks: the magic ``XDF:``, then
    per chunk the count of length bytes (1, 4 or 8), the length, and that many bytes (tag and content);
    a whole file ends exactly after its last chunk, a stream footer (tag 6)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if data[:4] != b"XDF:":
        return f"holds {len(data)} bytes and no XDF header"
    pos, tag = 4, None
    while pos < len(data):
        width = data[pos]
        if width not in (1, 4, 8) or pos + 1 + width > len(data):
            return f"cut at {len(data)} bytes, inside a chunk"
        length = int.from_bytes(data[pos + 1:pos + 1 + width], "little")
        start = pos + 1 + width
        if length < 2 or start + length > len(data):
            return f"cut at {len(data)} bytes, inside a chunk of {length} bytes"
        tag = int.from_bytes(data[start:start + 2], "little")
        pos = start + length
    if tag != 6:
        return f"ends at {len(data)} bytes without its stream footers"
    return None


class XdfUnavailable(EEGUnavailable):
    """No XDF recording: the engine is not installed, or it found no stream."""


def available() -> bool:
    """Whether LabRecorder's engine (the ``labrecorder`` package) is installed."""
    return importlib.util.find_spec("labrecorder") is not None


@dataclass
class XdfRecorder:
    """A running XDF recording (the child process); :meth:`stop` ends it and waits for the file."""

    path: Path
    log_path: Path
    process: subprocess.Popen
    source_ids: tuple[str, ...]
    flush_s: float = FLUSH_S
    ready: bool = False  # the recorder was connected when start returned

    @classmethod
    def start(cls, path: Path, source_ids: list[str] | tuple[str, ...], scope: str = "machine",
              log_path: Path | None = None, ready=None, timeout_s: float = 10.0,
              flush_s: float = FLUSH_S, resolve_s: float = 30.0) -> "XdfRecorder":
        """Start recording the streams ``source_ids`` into ``path``.

        ``ready()``: returns True once the recorder is connected (e.g. ``MarkerOutlet.has_consumers``);
        start returns when it does, or after ``timeout_s`` with the recorder still starting (``ready``
        False: a loaded machine; it keeps going and records from when it connects). The recorder
        looks for the streams for ``resolve_s`` and ends if one is missing. Raises
        :class:`XdfUnavailable` (one line, with the fix) when the engine is missing or the recorder
        ended (no such stream, no engine, a bad file name).
        """
        if not available():
            raise XdfUnavailable(f"session.xdf not recorded: LabRecorder's engine is not installed; {INSTALL_HINT}")
        path, ids = Path(path), tuple(source_ids)
        log_path = Path(log_path) if log_path is not None else path.with_suffix(".log")
        env = dict(os.environ, LSLAPICFG=config_file(scope), PYTHONUNBUFFERED="1")
        cmd = [sys.executable, "-m", "nao_trainer.eeg.xdf", "--out", str(path), "--timeout", str(resolve_s),
               "--flush", str(flush_s), "--parent", str(os.getpid()), *ids]
        with open(log_path, "ab") as log:
            # own session: Ctrl-C in the terminal reaches the session, which then stops the recorder in order
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=log, stderr=subprocess.STDOUT, env=env,
                                    start_new_session=True, close_fds=True)
        rec = cls(path, log_path, proc, ids, flush_s)
        try:
            rec._wait_ready(ready, timeout_s)
        except BaseException:  # SIGTERM/Ctrl-C (Interrupted) during start-up included: never leave the child behind
            rec.kill()
            raise
        return rec

    def _wait_ready(self, ready, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise XdfUnavailable(f"session.xdf not recorded: "
                                     f"{self.log_tail() or f'recorder exited ({self.process.returncode})'}")
            if self._recording() and (ready is None or ready()):
                self.ready = True
                return
            time.sleep(0.02)

    def _recording(self) -> bool:
        """The child said it started the engine (its own line in the log)."""
        try:
            return "xdf: recording" in self.log_path.read_text(errors="replace")
        except OSError:
            return False

    @property
    def running(self) -> bool:
        return self.process.poll() is None

    def log_tail(self) -> str:
        """The last line the recorder wrote that says what went wrong."""
        try:
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.startswith("xdf:")]
        except OSError:
            return ""
        return lines[-1][4:].strip() if lines else ""

    def stop(self, timeout_s: float = 10.0) -> int:
        """Ask the recorder to finish (it records ``flush_s`` more, then writes the footers); its exit code."""
        if self.process.poll() is None:
            try:
                self.process.stdin.write(b"stop\n")
                self.process.stdin.close()
            except (BrokenPipeError, OSError, ValueError):
                pass
            try:
                self.process.wait(self.flush_s + timeout_s)
            except subprocess.TimeoutExpired:
                self.kill()
        elif self.process.stdin is not None and not self.process.stdin.closed:
            self.process.stdin.close()
        return self.process.returncode

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(5.0)
        if self.process.stdin is not None and not self.process.stdin.closed:
            try:
                self.process.stdin.close()
            except OSError:
                pass


# ----------------------------------------------------------------------------------------------
# The child process
# ----------------------------------------------------------------------------------------------


def _resolve(source_ids: tuple[str, ...], timeout_s: float):
    """StreamInfos of every source_id (a continuous resolver answers on time; see platform notes)."""
    import pylsl

    pred = " or ".join(f"source_id='{s}'" for s in source_ids)
    resolver = pylsl.ContinuousResolver(pred=pred, forget_after=5.0)
    deadline = time.monotonic() + timeout_s
    found = {}
    while time.monotonic() < deadline:
        found = {i.source_id(): i for i in resolver.results() if i.source_id() in source_ids}
        if len(found) == len(source_ids):
            return [found[s] for s in source_ids]
        time.sleep(0.05)
    missing = [s for s in source_ids if s not in found]
    raise XdfUnavailable(f"no LSL stream with source_id {', '.join(missing)} within {timeout_s:g} s")


def _die_with_parent(parent: int | None) -> None:
    """Linux: the kernel sends this process SIGTERM when the session's process dies (``prctl``
    ``PR_SET_PDEATHSIG``), even by SIGKILL: the recorder never outlives its session. Elsewhere the
    closed stdin does it once recording (and the parent kills it on every exit path of ``start``)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if parent is not None and os.getppid() != parent:  # it died before the request took effect
        os.kill(os.getpid(), signal.SIGTERM)


def _ppid_of(pid: int) -> int | None:
    """The parent of ``pid`` from /proc (None where /proc cannot tell)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return int(fh.read().rsplit(b")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def start_guard(parent: int, grace_s: float, poll_s: float = 0.5) -> int | None:
    """Linux: fork a guard that SIGKILLs this process ``grace_s`` after its parent ``parent`` is gone.

    The graceful ends (stdin closed, SIGTERM from ``PR_SET_PDEATHSIG``, the SIGALRM stop limit) all
    need the interpreter to run, and the engine can block holding the GIL while liblsl retries its
    time-correction queries to streams that vanished with the session: two recorders were seen
    alive 12 and 17 minutes after their session was killed, deaf to SIGTERM. The guard is another
    process, so nothing the recorder holds can stop it; it dies with the recorder (its own
    ``PR_SET_PDEATHSIG``: SIGKILL) and only ever calls the OS. Call it before any thread starts.
    Returns the guard's pid in the recorder (None where it is not available)."""
    if not sys.platform.startswith("linux") or _ppid_of(os.getpid()) != parent:
        return None
    recorder = os.getpid()
    pid = os.fork()
    if pid:
        return pid
    try:  # the guard: no Python-level clean-up, no buffers flushed, only OS calls
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if os.getppid() == recorder:
            while _ppid_of(recorder) == parent:  # reparented (or gone) once the session has exited
                time.sleep(poll_s)
            time.sleep(grace_s)
            os.kill(recorder, signal.SIGKILL)
    finally:
        os._exit(0)


def main(argv: list[str] | None = None) -> int:
    """The recorder: record until stdin says ``stop`` or closes (the session ended or died), then flush."""
    ap = argparse.ArgumentParser(prog="python -m nao_trainer.eeg.xdf")
    ap.add_argument("--out", required=True)
    ap.add_argument("--timeout", type=float, default=10.0)
    ap.add_argument("--flush", type=float, default=FLUSH_S)
    ap.add_argument("--parent", type=int, default=None, help="the session's process id (the recorder dies with it)")
    ap.add_argument("source_ids", nargs="+")
    args = ap.parse_args(argv)
    recording = threading.Event()
    stop = threading.Event()

    def on_term(*_: object) -> None:
        if not recording.is_set():
            raise SystemExit(143)  # still looking for the streams: nothing to save, end now
        stop.set()  # recording: finish the file (flush, footers)

    signal.signal(signal.SIGTERM, on_term)
    _die_with_parent(args.parent)
    if args.parent is not None:  # the last resort when the interpreter cannot run any of the graceful ends
        start_guard(args.parent, args.flush + STOP_LIMIT_S + GUARD_EXTRA_S)
    if not os.environ.get("LSLAPICFG"):  # the engine's liblsl would discover streams beyond this machine
        print("xdf: LSLAPICFG is not set; refusing to record", flush=True)
        return 2
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the session decides when the recording ends
    try:
        infos = _resolve(tuple(args.source_ids), args.timeout)
    except XdfUnavailable as exc:
        print(f"xdf: {exc}", flush=True)
        return 4
    import labrecorder

    rec = labrecorder.Recording(args.out, infos)
    recording.set()
    print(f"xdf: recording {', '.join(args.source_ids)} to {args.out}", flush=True)

    def wait_stdin() -> None:
        try:
            while sys.stdin.buffer.readline() not in (b"", b"stop\n"):
                pass
        except OSError:
            pass
        stop.set()

    threading.Thread(target=wait_stdin, daemon=True).start()
    while not stop.wait(0.2):
        pass
    # The engine's stop can hang (liblsl's time-correction queries once the session's streams are gone) while
    # holding the GIL, so no Python thread can end it: SIGALRM's default action ends the process, whatever holds
    # what. The file then lacks its footers; pyxdf reads it all the same.
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(int(math.ceil(args.flush + STOP_LIMIT_S)))
    time.sleep(args.flush)  # samples and markers still on their way into the file
    rec.stop()
    del rec  # the footers are written here
    signal.alarm(0)
    print("xdf: stopped", flush=True)
    return 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    os._exit(code)  # never wait for the recording engine's own threads: the recorder must not outlive its session
