"""Event waits with generous limits, for tests: a hang fails, a slow (loaded) machine never does.

No test asserts how long something took (the house rules): a call that must end by a deadline, an
interrupt or a refusal is run here and must *return or raise* within a limit far above any load;
what it returned or raised (the deadline's message, the interrupted state) is the behaviour checked.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

#: Far above any deadline in the tests, so only a hang reaches it.
HANG_S = 120.0


def returns(fn: Callable[[], Any], limit_s: float = HANG_S) -> Any:
    """``fn()``'s result (or its exception, re-raised) once it ends; AssertionError if it hangs."""
    out: dict[str, Any] = {}

    def call() -> None:
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            out["error"] = exc

    worker = threading.Thread(target=call, daemon=True)
    worker.start()
    worker.join(limit_s)
    assert not worker.is_alive(), f"{getattr(fn, '__name__', fn)} did not end within {limit_s:g} s: it hangs"
    if "error" in out:
        raise out["error"]
    return out.get("value")
