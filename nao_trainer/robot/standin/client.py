"""The stand-in's control service seen from another process: press buttons, read the transcript."""
from __future__ import annotations

import os
import time
from typing import Any

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import RobotUnavailable  # noqa: E402
from nao_trainer.robot.standin.recorder import check_speed  # noqa: E402


class StandInClient:
    """The stand-in's control service seen from another process (a simulated participant, a test).

    ``StandInClient.connect(url)`` then ``press("A")``, ``transcript()``, ``clear()``,
    ``set_speed(x)``; ``close()`` when done.
    """

    def __init__(self, session: Any, url: str, control: Any) -> None:
        self._session = session
        self.url = url
        self._control = control

    @classmethod
    def connect(cls, url: str, deadline_s: float = 5.0) -> "StandInClient":
        """Connect within ``deadline_s`` (lookup of the control service included) or raise RobotUnavailable."""
        deadline = time.monotonic() + deadline_s
        session = qi.Session()

        def wait(future: Any) -> bool:
            left_ms = max(1, int((deadline - time.monotonic()) * 1000))
            return future.wait(left_ms) != qi.FutureState.Running

        connecting = session.connect(url, _async=True)
        if not wait(connecting):
            session.close()
            raise RobotUnavailable(f"no answer from the stand-in at {url} within {deadline_s:g} s: is it a `nao-trainer mock-robot`?")
        if connecting.hasError():
            error = " ".join(connecting.error().split())
            session.close()
            raise RobotUnavailable(f"cannot reach the stand-in at {url} ({error}): is `nao-trainer mock-robot` running there?")
        lookup = session.service("NaoTrainerStandIn", _async=True)
        if not wait(lookup) or lookup.hasError():
            reason = "no answer" if lookup.isRunning() else " ".join(lookup.error().split())
            session.close()
            raise RobotUnavailable(
                f"{url} offers no NaoTrainerStandIn control service ({reason}): it is not a `nao-trainer mock-robot`"
            )
        return cls(session, url, lookup.value())

    def press(self, button: str) -> str:
        """Touch and release a head button (letter A/B/C or ALMemory key); returns the key."""
        try:
            return self._control.press(button)
        except RuntimeError as exc:
            if "unknown head button" in str(exc):
                raise ValueError(str(exc).strip().splitlines()[0]) from None
            raise

    def hold(self, button: str, seconds: float) -> str:
        """A hand on the head for ``seconds`` (robot time): "asleep", "activity stopped" or "nothing"."""
        return self._control.hold(button, float(seconds))

    def hold_after(self, call: str, button: str, seconds: float) -> None:
        self._control.hold_after(call, button, float(seconds))

    def chest(self, clicks: int) -> str:
        return str(self._control.chest(int(clicks)))

    def chest_after(self, call: str, clicks: int) -> None:
        self._control.chest_after(call, int(clicks))

    def bounce(self, button: str, contacts: int) -> None:
        self._control.bounce(button, int(contacts))

    def body(self) -> dict[str, Any]:
        """Autonomous Life state, motors_on, posture, asleep, volume, muted, battery."""
        return dict(self._control.body())

    def set_battery(self, percent: int) -> None:
        self._control.set_battery(int(percent))

    def warm(self, joint: str, celsius: float) -> None:
        """``joint``'s temperature (°C), as ``check`` reads it."""
        self._control.warm(str(joint), float(celsius))

    def set_latency(self, round_trip_s: float = 0.0, beep_s: float = 0.0) -> None:
        self._control.set_latency(float(round_trip_s), float(beep_s))

    def freeze(self, seconds: float) -> None:
        """The link goes silent for ``seconds`` (wall time), starting just after this call returns."""
        self._control.freeze(float(seconds))

    def freeze_after(self, call: str, seconds: float) -> None:
        self._control.freeze_after(call, float(seconds))

    def freeze_at(self, call: str, seconds: float) -> None:
        self._control.freeze_at(call, float(seconds))

    def transcript(self) -> list[dict[str, Any]]:
        return [dict(e) for e in self._control.transcript()]

    def clear(self) -> None:
        self._control.clear()

    def set_speed(self, speed: float) -> None:
        self._control.set_speed(check_speed(speed))

    def speed(self) -> float:
        return float(self._control.speed())

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> "StandInClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
