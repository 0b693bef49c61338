"""The robot over NAOqi: a ``qi`` client implementing ``nao_trainer.ports.Robot``.

Works with a NAO on NAOqi <= 2.8 (``tcp://IP:9559``), NAOqi 2.9 (``tcps://IP:9503`` plus a user
and password from ``NAO_USER`` / ``NAO_PASSWORD``) and the project's stand-in
(``nao-trainer mock-robot``). Every remote call runs as a ``qi.Future`` waited on with a deadline,
so a silent robot cannot freeze a session; a dropped link surfaces as
``ports.RobotConnectionLost`` so the session can pause and call ``reconnect``.
"""
from __future__ import annotations

import atexit
import logging
import os
import threading
import time
import weakref
from typing import Any, Callable

os.environ.setdefault("QI_LOG_LEVEL", "silent")  # qi logs to fd 1 otherwise; must precede `import qi`
import qi  # noqa: E402

from nao_trainer.errors import ConfigError, RobotUnavailable  # noqa: E402
from nao_trainer.ports import (BUTTON_LETTERS, BeepTiming, RobotCallFailed, RobotConnectionLost,  # noqa: E402
                               check_beep)
from nao_trainer.robot.qi_calls import (  # noqa: E402,F401
    STANDIN_HINT, CallTimeouts, connect_session, explain_error, new_session, wait_future, is_connection_lost)
from nao_trainer.robot.address import (  # noqa: E402,F401 - re-exported: the client's public names
    PASSWORD_ENV, USER_ENV, Credentials, AuthenticatorFactory, resolve_host, credentials_from_env, normalize_url,
    redact_url)
from nao_trainer.robot.watchdog import LinkWatchdog  # noqa: E402

log = logging.getLogger(__name__)

BODY_LANGUAGE_MODES = ("disabled", "random", "contextual")


class MissingService(RobotUnavailable):
    """The robot is connected but does not offer a NAOqi service the project needs."""


# ------------------------------------------------------------------------------------------------
# The robot
# ------------------------------------------------------------------------------------------------


class NaoqiRobot:
    """A NAO (or the stand-in) reached over ``qi``; implements ``nao_trainer.ports.Robot``.

    Create it with ``NaoqiRobot.connect(url)``. Head-button callbacks run on qi's threads; the
    robot guards its own state, the callback must guard the caller's. Call ``close()`` before the
    process exits (live signal subscriptions can abort the process at exit).
    """

    def __init__(
        self,
        session: Any,
        url: str,
        credentials: Credentials | None = None,
        timeouts: CallTimeouts = CallTimeouts(),
        debounce_s: float = 0.15,
        buttons: dict[str, str] | None = None,
    ) -> None:
        self._session = session
        #: ALMemory key of each answer button -> letter (the robot model's; a NAO's head by default).
        self.buttons: dict[str, str] = dict(buttons if buttons is not None else BUTTON_LETTERS)
        #: Optional services the robot lacks (``RobotModel.probe``): calls that need them degrade, said once.
        self.without: set[str] = set()
        self._watches: dict[str, Callable[[Any], None]] = {}  # ALMemory event -> callback (robot health)
        self._watch_subs: list[tuple[str, Any, Any]] = []
        self.url = url
        self._credentials = credentials
        self.timeouts = timeouts
        self.debounce_s = float(debounce_s)
        self._lock = threading.RLock()
        # Held while a button callback runs, so unsubscribe_buttons() returns only after it ends.
        self._dispatch = threading.RLock()
        self._services: dict[str, Any] = {}
        self._button_callback: Callable[[str, float], None] | None = None
        self._subscriptions: list[tuple[str, Any, Any]] = []  # (key, subscriber proxy, link id)
        self._last_press: dict[str, float] = {}
        self._closed = False
        #: Called after each successful ``reconnect`` (e.g. put Autonomous Life back in the task's state).
        self.after_reconnect: list[Callable[[], None]] = []
        #: The watchdog's pace during answer windows (wall seconds); the session sets them from the study.
        self.link_check_s, self.link_deadline_s = 1.0, 2.0
        _LIVE.add(self)

    # -- connection ------------------------------------------------------------------------------

    @classmethod
    def connect(
        cls,
        url: str,
        deadline_s: float = 10.0,
        credentials: Credentials | None = None,
        *,
        timeouts: CallTimeouts = CallTimeouts(),
        debounce_s: float = 0.15,
        buttons: dict[str, str] | None = None,
    ) -> "NaoqiRobot":
        """Connect within ``deadline_s`` or raise RobotUnavailable (a one-line, user-fixable message).

        ``tcps://`` (NAOqi 2.9) needs credentials: given here or, when None, from
        ``NAO_USER`` / ``NAO_PASSWORD``.
        """
        qi_url = normalize_url(url)
        if debounce_s < 0:
            raise ConfigError(f"button debounce must be >= 0 seconds, got {debounce_s!r}")
        if deadline_s <= 0:
            raise ConfigError(f"robot connect deadline must be > 0 seconds, got {deadline_s!r}")
        creds = credentials if credentials is not None else credentials_from_env()
        if qi_url.startswith("tcps://") and creds is None:
            raise ConfigError(
                f"robot address {qi_url} is NAOqi 2.9 (tcps): set {USER_ENV} and {PASSWORD_ENV} in the environment"
            )
        resolve_host(qi_url, deadline_s)
        session = new_session(creds)
        connect_session(session, qi_url, deadline_s)
        log.info("connected to the robot at %s", qi_url)
        return cls(session, qi_url, creds, timeouts, debounce_s, buttons)

    def is_connected(self) -> bool:
        """True while the qi session is up (it turns False soon after the robot drops)."""
        if self._closed:
            return False
        try:
            return bool(self._session.isConnected())
        except RuntimeError:
            return False

    def reconnect(self, deadline_s: float) -> None:
        """Connect the session again, re-fetch services and re-subscribe the buttons.

        Raises RobotUnavailable when the robot is not back within ``deadline_s``; the caller
        may try again later (the session does, with backoff).
        """
        if self._closed:
            raise RobotUnavailable(f"the connection to the robot at {self.url} was closed; create a new one")
        if deadline_s <= 0:
            raise ValueError(f"reconnect deadline must be > 0 seconds, got {deadline_s!r}")
        deadline = time.monotonic() + deadline_s
        callback = self._button_callback
        # Old signals: instant on a dead link, bounded on a frozen one (a quarter of the budget).
        self._drop_subscriptions(budget_s=min(2.0, deadline_s / 4))
        with self._lock:
            old_watches, self._watch_subs = self._watch_subs, []
        self._disconnect_all(old_watches, budget_s=min(2.0, deadline_s / 4))
        with self._lock:
            self._services.clear()
        if self._session.isConnected():
            self._session.close()
        try:
            connect_session(self._session, self.url, max(0.05, deadline - time.monotonic()))
        except RobotUnavailable:
            # A timed-out connect leaves the session closed mid-handshake; start the next try afresh.
            self._session = new_session(self._credentials)
            raise
        if callback is not None or self._watches:
            self._wait_for_service("ALMemory", max(0.5, deadline - time.monotonic()))
        if callback is not None:
            self.subscribe_buttons(callback)
        if self._watches:
            self._subscribe_watches()
        log.info("reconnected to the robot at %s", self.url)
        for hook in list(self.after_reconnect):
            hook()

    def close(self) -> None:
        """Unsubscribe the buttons and close the qi session. Idempotent."""
        if self._closed:
            return
        try:
            self.unsubscribe_buttons()
            self.unwatch_all()
        finally:
            self._closed = True
            _LIVE.discard(self)
            with self._lock:
                self._services.clear()
            try:
                self._session.close()
            except RuntimeError as exc:  # already gone: nothing left to release
                log.debug("closing the qi session: %s", exc)

    def __enter__(self) -> "NaoqiRobot":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"NaoqiRobot(url={redact_url(self.url)!r}, connected={self.is_connected()})"

    # -- speech, sound, LEDs, posture ----------------------------------------------------------------

    def say(self, text: str, animated: bool = False, mode: str = "contextual") -> None:
        """Speak ``text`` and return when done; ``animated`` adds gestures (body language ``mode``)."""
        if not isinstance(text, str):
            raise TypeError(f"say() needs a str, got {type(text).__name__}")
        if animated and "ALAnimatedSpeech" in self.without:
            animated = False  # the model degrades: plain speech (said once, at the start)
        if animated:
            if mode not in BODY_LANGUAGE_MODES:
                raise ValueError(f"body language mode must be one of {', '.join(BODY_LANGUAGE_MODES)}, got {mode!r}")
            self._call("ALAnimatedSpeech", "say", text, {"bodyLanguageMode": mode}, timeout_s=self.timeouts.say(text))
        else:
            self._call("ALTextToSpeech", "say", text, timeout_s=self.timeouts.say(text))

    def beep(self, frequency_hz: int, duration_s: float, gain: float = 0.5) -> BeepTiming:
        """Play a sine beep and return once played (gain 0..1, centred), with when it sounded.

        A cheap call first measures the round trip; the onset is estimated as the reply's arrival
        minus the duration minus half that round trip (docs/how-to/robot.md says what is assumed).
        """
        check_beep(frequency_hz, duration_s, gain)
        self._service("ALAudioPlayer")  # looked up before timing: the lookup is not part of the beep
        rtt = self.ping(self.timeouts.default_s)
        start = time.monotonic()
        self._call(
            "ALAudioPlayer",
            "playSine",
            int(frequency_hz),
            int(round(float(gain) * 100)),
            0,
            float(duration_s),
            timeout_s=self.timeouts.default_s + float(duration_s),
        )
        returned = time.monotonic()
        onset = max(start, returned - float(duration_s) - rtt / 2)
        return BeepTiming(start, returned, rtt, float(duration_s), onset)

    def ping(self, deadline_s: float) -> float:
        """One cheap call (ALMemory.getData of a head button); its round trip in seconds.

        ``RobotConnectionLost`` when no answer comes within ``deadline_s``.
        """
        t0 = time.monotonic()
        self._call("ALMemory", "getData", next(iter(self.buttons), "FrontTactilTouched"), timeout_s=deadline_s)
        return time.monotonic() - t0

    def watch_link(self) -> LinkWatchdog:
        """A watchdog for a quiet stretch (``with robot.watch_link() as w: ...``; then ``w.lost``)."""
        return LinkWatchdog(self.ping, self.link_check_s, self.link_deadline_s)

    def call(self, service: str, method: str, *args: Any, timeout_s: float | None = None) -> Any:
        """Any NAOqi call, with a deadline (default ``timeouts.default_s``); for status and set-up calls."""
        return self._call(service, method, *args, timeout_s=self.timeouts.default_s if timeout_s is None else timeout_s)

    def set_eye_leds(self, rgb: int, duration_s: float) -> None:
        """Fade the face LEDs to ``0xRRGGBB`` over ``duration_s`` seconds."""
        if not isinstance(rgb, int) or not 0 <= rgb <= 0xFFFFFF:
            raise ValueError(f"eye colour must be an int 0x000000..0xFFFFFF, got {rgb!r}")
        if not 0.0 <= float(duration_s) <= 60.0:
            raise ValueError(f"LED fade duration must be in [0, 60] seconds, got {duration_s!r}")
        if "ALLeds" in self.without:
            return  # the model degrades: no eye colours (said once, at the start)
        self._call("ALLeds", "fadeRGB", "FaceLeds", int(rgb), float(duration_s),
                   timeout_s=self.timeouts.default_s + float(duration_s))

    def go_to_posture(self, name: str, speed: float) -> bool:
        """Go to a predefined posture (Stand, StandInit, Crouch, Sit...); False if the robot could not."""
        if not 0.0 < float(speed) <= 1.0:
            raise ValueError(f"posture speed must be in (0, 1], got {speed!r}")
        ok = bool(self._call("ALRobotPosture", "goToPosture", str(name), float(speed), timeout_s=self.timeouts.posture_s))
        if not ok:
            log.warning("the robot could not reach posture %s", name)
        return ok

    def wake_up(self) -> bool:
        """Stiffen the joints and stand (ALMotion.wakeUp); False when the robot refused ("True if the call
        succeeded", ``naoqi/motion/control-stiffness-api.html``: a robot resting after a critical heat says no)."""
        return self._call("ALMotion", "wakeUp", timeout_s=self.timeouts.posture_s) is not False

    def rest(self) -> None:
        """The safe end state: crouch and release the joints' stiffness (ALMotion.rest)."""
        self._call("ALMotion", "rest", timeout_s=self.timeouts.posture_s)

    def stop_all(self) -> None:
        """Cut speech and sounds short (ALTextToSpeech.stopAll, ALAudioPlayer.stopAll).

        Safe to call from another thread while ``say`` blocks: that ``say`` then returns early.
        """
        self._call("ALTextToSpeech", "stopAll", timeout_s=self.timeouts.default_s)
        self._call("ALAudioPlayer", "stopAll", timeout_s=self.timeouts.default_s)

    # -- what the robot offers (the pre-session check) ----------------------------------------------

    def has_service(self, name: str) -> bool:
        """Whether the robot offers the NAOqi service ``name`` (looked up once, then cached)."""
        try:
            self._service(name)
        except MissingService:
            return False
        return True

    def speech_volume(self) -> float:
        """The text-to-speech volume, 0..1 (ALTextToSpeech.getVolume)."""
        return float(self._call("ALTextToSpeech", "getVolume", timeout_s=self.timeouts.default_s))

    # -- head buttons ------------------------------------------------------------------------------

    def subscribe_buttons(self, callback: Callable[[str, float], None]) -> None:
        """Call ``callback(letter, time.monotonic())`` on each head-button press (debounced).

        Replaces an earlier subscription. The callback runs on a qi thread.
        """
        self.unsubscribe_buttons()
        budget = self.timeouts.subscribe_s  # for the whole subscription, not per call
        deadline = time.monotonic() + budget

        def left() -> float:
            return max(0.001, deadline - time.monotonic())

        memory = self._service("ALMemory", budget)
        subscriptions: list[tuple[str, Any, Any]] = []
        try:
            for key in self.buttons:
                sub = self._remote(memory, "subscriber", key, timeout_s=left(), what=f"ALMemory.subscriber({key})", budget_s=budget)
                link = self._remote(
                    sub.signal, "connect", _ButtonHandler(self, key),
                    timeout_s=left(), what=f"{key} signal connect", budget_s=budget,
                )
                subscriptions.append((key, sub, link))  # keep the proxy: dropping it silences the signal
        except BaseException:
            self._disconnect_all(subscriptions)
            raise
        with self._lock:
            self._subscriptions = subscriptions
            self._button_callback = callback
            self._last_press.clear()

    def unsubscribe_buttons(self) -> None:
        """Disconnect the head-button signals; no callback runs any more once this returns.

        Waits for a callback in progress to finish (do not call it while holding a lock the
        callback needs).
        """
        with self._dispatch, self._lock:
            self._button_callback = None
        self._drop_subscriptions()

    # -- ALMemory events (the robot's health) ------------------------------------------------------

    def watch(self, events: dict[str, Callable[[Any], None]]) -> None:
        """Call ``events[key](value)`` on each ALMemory event ``key`` (a qi thread); subscribed again after a
        reconnection. Replaces an earlier ``watch``. A key the robot refuses to subscribe is skipped (logged)."""
        self.unwatch_all()
        with self._lock:
            self._watches = dict(events)
        self._subscribe_watches()

    def _subscribe_watches(self) -> None:
        budget = self.timeouts.subscribe_s
        deadline = time.monotonic() + budget
        memory = self._service("ALMemory", budget)
        subs: list[tuple[str, Any, Any]] = []
        with self._lock:
            watches = dict(self._watches)
        for key, callback in watches.items():
            try:
                sub = self._remote(memory, "subscriber", key, timeout_s=max(0.001, deadline - time.monotonic()),
                                   what=f"ALMemory.subscriber({key})", budget_s=budget)
                link = self._remote(sub.signal, "connect", _EventHandler(self, key, callback),
                                    timeout_s=max(0.001, deadline - time.monotonic()), what=f"{key} signal connect",
                                    budget_s=budget)
            except RobotCallFailed as exc:
                log.warning("not watching %s: %s", key, exc)
                continue
            subs.append((key, sub, link))
        with self._lock:
            self._watch_subs = subs

    def unwatch_all(self) -> None:
        """Disconnect the event subscriptions of ``watch``; no event callback runs once this returns."""
        with self._dispatch, self._lock:
            self._watches = {}
            subs, self._watch_subs = self._watch_subs, []
        self._disconnect_all(subs)

    def _on_event(self, key: str, callback: Callable[[Any], None], value: Any) -> None:
        with self._dispatch:
            with self._lock:
                if key not in self._watches:
                    return
            try:
                callback(value)
            except Exception:  # an exception here would vanish inside qi: log it loudly instead
                log.exception("robot event callback failed for %s", key)

    def _drop_subscriptions(self, budget_s: float | None = None) -> None:
        with self._lock:
            subscriptions, self._subscriptions = self._subscriptions, []
        self._disconnect_all(subscriptions, budget_s)

    def _disconnect_all(self, subscriptions: list[tuple[str, Any, Any]], budget_s: float | None = None) -> None:
        """Disconnect all signals at once with one shared budget, so a frozen robot delays close by 2 s at most."""
        pending = []
        for key, sub, link in subscriptions:
            try:
                pending.append((key, sub.signal.disconnect(link, _async=True)))
            except RuntimeError as exc:  # the robot is gone: nothing to disconnect from
                log.debug("disconnecting %s: %s", key, exc)
        deadline = time.monotonic() + (min(2.0, self.timeouts.subscribe_s) if budget_s is None else budget_s)
        for key, fut in pending:
            if not wait_future(fut, max(0.001, deadline - time.monotonic())):
                log.debug("disconnecting %s timed out", key)

    def _on_button(self, key: str, value: Any) -> None:
        """A value arrived on a button key (qi thread): forward presses, drop releases and bounces."""
        try:
            pressed = float(value) >= 0.5
        except (TypeError, ValueError):
            return
        if not pressed:
            return
        now = time.monotonic()
        with self._dispatch:
            with self._lock:
                callback = self._button_callback
                if callback is None:
                    return
                last = self._last_press.get(key)
                if last is not None and now - last < self.debounce_s:
                    return
                self._last_press[key] = now
            try:
                callback(self.buttons[key], now)
            except Exception:  # an exception here would vanish inside qi: log it loudly instead
                log.exception("head-button callback failed for %s", key)

    # -- calls ---------------------------------------------------------------------------------

    def _service(self, name: str, timeout_s: float | None = None) -> Any:
        with self._lock:
            proxy = self._services.get(name)
        if proxy is not None:
            return proxy
        self._check_open()
        timeout_s = self.timeouts.default_s if timeout_s is None else timeout_s
        try:
            proxy = self._remote(self._session, "service", name, timeout_s=timeout_s, what=f"service {name}")
        except RobotCallFailed as exc:
            if "cannot find service" in str(exc).lower():
                raise MissingService(
                    f"the robot at {self.url} offers no {name} service; check its NAOqi version "
                    "or turn off the feature that needs it"
                ) from None
            raise
        with self._lock:
            self._services[name] = proxy
        return proxy

    def _wait_for_service(self, name: str, timeout_s: float) -> None:
        """After a robot restart its services register one by one: wait until ``name`` is there."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self._service(name, max(0.1, deadline - time.monotonic()))
                return
            except (RobotConnectionLost, MissingService):
                if time.monotonic() >= deadline or not self._session.isConnected():
                    raise RobotUnavailable(
                        f"the robot at {self.url} came back without its {name} service within {timeout_s:g} s; "
                        "wait until it has finished booting and try again"
                    ) from None
                time.sleep(0.1)

    def _call(self, service: str, method: str, *args: Any, timeout_s: float) -> Any:
        """Call ``service.method(*args)``; ``timeout_s`` bounds the whole call, service lookup included."""
        deadline = time.monotonic() + timeout_s
        proxy = self._service(service, min(timeout_s, self.timeouts.default_s))
        remaining = max(0.001, deadline - time.monotonic())
        return self._remote(proxy, method, *args, timeout_s=remaining, what=f"{service}.{method}", budget_s=timeout_s)

    def _remote(
        self, target: Any, method: str, *args: Any, timeout_s: float, what: str, budget_s: float | None = None
    ) -> Any:
        """Run a qi call as a future with a deadline; map a lost link to RobotConnectionLost.

        ``budget_s`` is the caller's whole deadline when part of it was spent already (for the message).
        """
        self._check_open()
        try:
            future = getattr(target, method)(*args, _async=True)
        except RuntimeError as exc:
            raise self._translate(exc, what) from None
        if not wait_future(future, timeout_s):
            raise RobotConnectionLost(
                f"{what} on the robot at {self.url} did not answer within {budget_s or timeout_s:g} s; "
                "the robot may be frozen or unreachable"
            )
        if future.hasError():
            raise self._translate(RuntimeError(future.error()), what) from None
        if future.isCanceled():  # qi cancels pending calls when the link goes down
            raise RobotConnectionLost(f"{what}: the call was cancelled; lost the robot at {self.url}?")
        try:
            return future.value()
        except RuntimeError as exc:
            raise self._translate(exc, what) from None

    def _translate(self, exc: RuntimeError, what: str) -> RobotConnectionLost | RobotCallFailed:
        # Remote Python errors arrive with a traceback ("At: ..."): keep the first line.
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        message = lines[0] if lines else type(exc).__name__
        if is_connection_lost(message) or not self.is_connected():
            return RobotConnectionLost(f"{what}: lost the robot at {self.url} ({message})")
        return RobotCallFailed(f"{what} failed on the robot at {self.url}: {message}")

    def _check_open(self) -> None:
        if self._closed:
            raise RobotCallFailed(f"the connection to the robot at {self.url} is closed")


#: Robots not yet closed; closed at interpreter exit as a safety net (live signal subscriptions
#: at exit abort the process now and then, see docs/how-to/robot.md).
_LIVE: "weakref.WeakSet[NaoqiRobot]" = weakref.WeakSet()


@atexit.register
def _close_live_robots() -> None:
    for robot in list(_LIVE):
        try:
            robot.close()
        except Exception as exc:  # noqa: BLE001 - exiting anyway; say why, then go on
            log.debug("closing %r at exit: %s", robot, exc)


class _EventHandler:
    """A signal callback for one watched ALMemory event (a class: qi keeps a stable reference)."""

    def __init__(self, robot: NaoqiRobot, key: str, callback: Callable[[Any], None]) -> None:
        self._robot, self._key, self._callback = robot, key, callback

    def __call__(self, value: Any) -> None:
        self._robot._on_event(self._key, self._callback, value)


class _ButtonHandler:
    """A signal callback bound to one key; a class (not a lambda) so qi keeps a stable reference."""

    def __init__(self, robot: NaoqiRobot, key: str) -> None:
        self._robot = robot
        self._key = key

    def __call__(self, value: Any) -> None:
        self._robot._on_button(self._key, value)
