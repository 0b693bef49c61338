"""A robot without a robot: the laptop speaks and beeps (``--robot desktop``), for pilots without a NAO.

Implements ``nao_trainer.ports.Robot``. Speech comes from a real speech engine, espeak-ng (an OS
package), beeps are sine tones. Audio goes to the sound device through the first player found
(``pw-play``, ``paplay``, ``aplay``); with no sound device (a server, CI) each utterance and beep
is written as a WAV file into the session folder's ``audio/`` instead, and the robot waits as long
as the sound lasts (divided by the session's speed), so the session keeps its rhythm.
``NAO_TRAINER_AUDIO=files`` forces the files, ``=device`` the sound device.

The desktop has no head buttons, LEDs or posture: answers come from the keyboard (or a simulated
participant), and LEDs/postures are no-ops that succeed.
"""
from __future__ import annotations

import logging
import os
import shutil
import subprocess
import tempfile
import threading
import wave
from pathlib import Path
from typing import Callable

import numpy as np

from nao_trainer.errors import ConfigError, RobotUnavailable
from nao_trainer.ports import RobotCallFailed, check_beep

log = logging.getLogger(__name__)

SPEECH_ENGINE = "espeak-ng"
INSTALL_HINT = ("install it: `sudo apt-get install espeak-ng` (Debian/Ubuntu), `sudo dnf install espeak-ng` (Fedora), "
                "`brew install espeak-ng` (macOS)")
PLAYERS = ("pw-play", "paplay", "aplay")
AUDIO_ENV = "NAO_TRAINER_AUDIO"
RATE_HZ = 22050
#: Speech rate in words per minute (espeak-ng's default is 175; a little slower suits the task).
WORDS_PER_MINUTE = 160
_SYNTH_TIMEOUT_S = 30.0


def sound_device_present() -> bool:
    """Whether this machine has a sound output a player can reach (ALSA card, PulseAudio or PipeWire)."""
    runtime = os.environ.get("XDG_RUNTIME_DIR", "")
    if os.environ.get("PULSE_SERVER") or (runtime and any(
            Path(runtime, name).exists() for name in ("pulse/native", "pipewire-0"))):
        return True
    try:
        cards = Path("/proc/asound/cards").read_text()
    except OSError:
        return False
    return bool(cards.strip()) and "no soundcards" not in cards


def choose_player(environ: dict[str, str] | None = None) -> list[str] | None:
    """The command that plays a WAV file on the sound device, or None to write files instead."""
    env = os.environ if environ is None else environ
    wanted = env.get(AUDIO_ENV, "auto").strip().lower() or "auto"
    if wanted not in ("auto", "files", "device"):
        raise ConfigError(f"{AUDIO_ENV}={wanted!r}: use auto, files or device")
    if wanted == "files":
        return None
    player = next((p for p in PLAYERS if shutil.which(p)), None)
    if wanted == "device":
        if player is None:
            raise RobotUnavailable(f"{AUDIO_ENV}=device but no audio player is installed ({', '.join(PLAYERS)}): "
                                   "install alsa-utils or pulseaudio-utils, or unset it to write WAV files")
        return [player]
    return [player] if player and sound_device_present() else None


def sine_beep(frequency_hz: float, duration_s: float, gain: float, rate_hz: int = RATE_HZ) -> np.ndarray:
    """A sine tone as int16 samples, with 5 ms ramps so it does not click."""
    n = max(1, int(round(duration_s * rate_hz)))
    t = np.arange(n) / rate_hz
    tone = np.sin(2 * np.pi * frequency_hz * t)
    ramp = min(n // 2, int(0.005 * rate_hz))
    if ramp:
        envelope = np.ones(n)
        envelope[:ramp] = np.linspace(0.0, 1.0, ramp)
        envelope[-ramp:] = np.linspace(1.0, 0.0, ramp)
        tone *= envelope
    return np.round(tone * gain * 32767 * 0.9).astype("<i2")


def write_wav(path: Path, samples: np.ndarray, rate_hz: int = RATE_HZ) -> None:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate_hz)
        w.writeframes(np.ascontiguousarray(samples, dtype="<i2").tobytes())


def wav_duration(path: Path) -> float:
    with wave.open(str(path), "rb") as w:
        return w.getnframes() / float(w.getframerate())


class DesktopRobot:
    """The laptop as the robot (``ports.Robot``): espeak-ng speech and sine beeps.

    ``speed`` divides the waits of the WAV-file mode (as it divides every wait of a session).
    Call ``record_audio_to(folder)`` once the session folder exists: sounds made before that are
    played or timed but not kept.
    """

    def __init__(self, speed: float = 1.0, player: list[str] | None = None, voice: str = "en") -> None:
        self.speed = float(speed)
        self.player = player
        self.voice = voice
        self.audio_dir: Path | None = None
        self._count = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._proc: subprocess.Popen | None = None
        self._closed = False
        self._tmp = Path(tempfile.mkdtemp(prefix="nao-trainer-desktop-"))

    @classmethod
    def start(cls, speed: float = 1.0, voice: str = "en") -> "DesktopRobot":
        """A desktop robot, or RobotUnavailable with an install hint when espeak-ng is missing."""
        if shutil.which(SPEECH_ENGINE) is None:
            raise RobotUnavailable(f"--robot desktop speaks through {SPEECH_ENGINE}, which is not installed; "
                                   f"{INSTALL_HINT}")
        return cls(speed, choose_player(), voice)

    @property
    def mode(self) -> str:
        return "sound device" if self.player else "WAV files"

    def record_audio_to(self, folder: Path) -> None:
        """Keep every later sound as ``folder/NNNN-say.wav`` / ``NNNN-beep.wav`` (WAV-file mode only)."""
        if self.player is None:
            folder.mkdir(parents=True, exist_ok=True)
            self.audio_dir = folder

    # -- ports.Robot ----------------------------------------------------------------------------

    def say(self, text: str, animated: bool = False, mode: str = "contextual") -> None:
        if not isinstance(text, str):
            raise TypeError(f"say() needs a str, got {type(text).__name__}")
        self._stop.clear()  # a stop_all from now on (also during the synthesis) cuts this utterance short
        path = self._next_path("say")
        try:
            with self._lock:
                self._proc = synth = subprocess.Popen(
                    [SPEECH_ENGINE, "-v", self.voice, "-s", str(WORDS_PER_MINUTE), "--stdin", "-w", str(path)],
                    stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            try:
                _, err = synth.communicate(text.encode("utf-8"), timeout=_SYNTH_TIMEOUT_S)
            except subprocess.TimeoutExpired as exc:
                synth.kill()
                synth.communicate()
                raise RobotUnavailable(f"{SPEECH_ENGINE} failed to speak ({exc}); {INSTALL_HINT}") from None
            finally:
                with self._lock:
                    self._proc = None
        except OSError as exc:
            raise RobotUnavailable(f"{SPEECH_ENGINE} failed to speak ({exc}); {INSTALL_HINT}") from None
        if self._stop.is_set():  # stopped while it was being synthesised: nothing to say
            path.unlink(missing_ok=True)
            return
        if synth.returncode != 0:
            why = err.decode("utf-8", "replace").strip().splitlines()
            raise RobotCallFailed(f"{SPEECH_ENGINE} could not speak {text[:40]!r}: {why[0] if why else synth.returncode}")
        self._output(path)

    def beep(self, frequency_hz: int, duration_s: float, gain: float = 0.5) -> None:
        check_beep(frequency_hz, duration_s, gain)
        self._stop.clear()
        path = self._next_path("beep")
        # The beep is short by design (its length is already divided by the speed): keep it as asked.
        write_wav(path, sine_beep(float(frequency_hz), float(duration_s), float(gain)))
        self._output(path, scaled=False)

    def set_eye_leds(self, rgb: int, duration_s: float) -> None:
        log.debug("desktop robot: eyes %06x", rgb)

    def go_to_posture(self, name: str, speed: float) -> bool:
        log.debug("desktop robot: posture %s", name)
        return True

    def stop_all(self) -> None:
        """Cut the current sound short (from any thread)."""
        self._stop.set()
        with self._lock:
            proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.terminate()

    def subscribe_buttons(self, callback: Callable[[str, float], None]) -> None:
        raise ConfigError("the desktop robot has no head buttons: answer with --input keyboard (or simulated)")

    def unsubscribe_buttons(self) -> None:
        pass

    def reconnect(self, deadline_s: float) -> None:
        pass

    def is_connected(self) -> bool:
        return not self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.stop_all()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __repr__(self) -> str:
        return f"DesktopRobot(audio={self.mode!r}, speed={self.speed:g})"

    # -- audio ----------------------------------------------------------------------------------

    def _next_path(self, kind: str) -> Path:
        if self._closed:
            raise RobotCallFailed("the desktop robot is closed")
        with self._lock:
            self._count += 1
            folder = self.audio_dir if self.audio_dir is not None and self.player is None else self._tmp
            return folder / f"{self._count:04d}-{kind}.wav"

    def _output(self, path: Path, scaled: bool = True) -> None:
        """Play ``path`` on the sound device, or wait as long as it lasts (files mode); interruptible.

        The stop flag is cleared by the caller before the sound is made, so a ``stop_all`` that comes while
        it is being made (speech synthesis takes a while) is not lost.
        """
        if self._stop.is_set():
            path.unlink(missing_ok=True)
            return
        if self.player is None:
            seconds = wav_duration(path) / (self.speed if scaled else 1.0)
            if path.parent == self._tmp:
                path.unlink(missing_ok=True)
            self._stop.wait(seconds)
            return
        try:
            with self._lock:
                self._proc = subprocess.Popen([*self.player, str(path)], stdout=subprocess.DEVNULL,
                                              stderr=subprocess.PIPE)
            _, err = self._proc.communicate()
            if self._proc.returncode not in (0, -15) and not self._stop.is_set():
                why = err.decode("utf-8", "replace").strip().splitlines()
                log.warning("%s could not play a sound: %s", self.player[0], why[0] if why else self._proc.returncode)
        finally:
            with self._lock:
                self._proc = None
            path.unlink(missing_ok=True)
