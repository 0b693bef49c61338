"""Fan-out of independent work items through joblib: local processes, or a dask.distributed cluster.

``fan_out(func, tasks, workers, backend)`` returns ``[func(*task) for task in tasks]`` in order.

* ``backend=None`` (or ``"local"``): joblib's process pool (loky) with ``workers`` processes; one
  worker or one task runs in this process.
* ``backend="dask://HOST:PORT"``: the tasks go to an existing dask.distributed scheduler through
  joblib's dask backend. Every worker needs nao-trainer installed (the same version): tasks are
  pickled by reference to this package's functions. A scheduler that does not answer within
  ``CONNECT_TIMEOUT_S`` is a one-line error; nothing hangs.

Results do not depend on the backend: every task carries its own seeds (tests compare them bit
for bit). joblib and dask are imported only when used.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from nao_trainer.errors import ConfigError, UserError, raise_if_interrupted

CONNECT_TIMEOUT_S = 10.0
DASK_PREFIX = "dask://"


class ClusterUnavailable(UserError):
    """The dask scheduler named by ``--backend`` cannot be reached."""


def check_backend(backend: str | None) -> str | None:
    """``None`` for local processes, else the ``tcp://HOST:PORT`` address; ConfigError on bad text."""
    if backend in (None, "", "local"):
        return None
    text = str(backend)
    if not text.startswith(DASK_PREFIX):
        raise ConfigError(f"--backend {text!r}: use 'local' or dask://HOST:PORT (a running `dask scheduler`)")
    address = text[len(DASK_PREFIX):]
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--backend {text!r}: use dask://HOST:PORT, e.g. dask://127.0.0.1:8786")
    return f"tcp://{address}"


def connect(address: str, timeout_s: float | None = None):
    """A ``distributed.Client`` for ``address``; ClusterUnavailable within ``timeout_s`` otherwise."""
    timeout_s = CONNECT_TIMEOUT_S if timeout_s is None else timeout_s
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError("--backend dask://... needs dask.distributed: pip install 'nao-trainer[all]'") from None
    try:
        return Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise ClusterUnavailable(
            f"{address}: no dask scheduler answered within {timeout_s:g} s ({type(exc).__name__}); start one with "
            "`dask scheduler` and workers with `dask worker HOST:8786` (see docs/explanation/evaluation.md), or drop --backend"
        ) from None


def fan_out(func: Callable[..., Any], tasks: Sequence[tuple], workers: int = 2, backend: str | None = None,
            client: Any = None, progress: str | None = None) -> list[Any]:
    """``[func(*t) for t in tasks]``, computed in parallel (see the module docstring). ``progress``: a label;
    each finished task is then said on stderr ("LABEL: 3/50 done, 41 s, about 640 s left")."""
    tasks = list(tasks)
    address = check_backend(backend)
    said = _Progress(progress, len(tasks))
    if address is None and client is None and (workers <= 1 or len(tasks) <= 1):
        return [said(func(*t)) for t in tasks]
    try:
        from joblib import Parallel, delayed, parallel_config
    except ImportError:
        raise ConfigError("parallel runs need joblib: pip install 'nao-trainer[all]'") from None
    jobs = [delayed(func)(*t) for t in tasks]
    if address is None and client is None:
        return [said(r) for r in Parallel(n_jobs=workers, backend="loky", return_as="generator")(jobs)]
    own = client is None
    client = client or connect(address)
    try:
        with parallel_config(backend="dask", client=client):
            return [said(r) for r in Parallel(n_jobs=-1, return_as="generator")(jobs)]
    finally:
        if own:
            client.close()


class _Progress:
    """Says on stderr how many of ``total`` tasks are done (nothing without a label)."""

    def __init__(self, label: str | None, total: int) -> None:
        import time

        self.label, self.total, self.done, self.clock = label, total, 0, time.monotonic
        self.t0 = self.clock()

    def __call__(self, result: Any) -> Any:
        raise_if_interrupted()  # a Ctrl-C that a library swallowed
        self.done += 1
        if self.label:
            import sys

            spent = self.clock() - self.t0
            left = spent / self.done * (self.total - self.done)
            print(f"{self.label}: {self.done}/{self.total} done, {spent:.0f} s"
                  + (f", about {left:.0f} s left" if self.done < self.total else ""), file=sys.stderr, flush=True)
        return result
