"""Answer inputs: press windows, the keyboard (through a real pipe), the head buttons of the
stand-in over real qi, and the simulated participant."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest
from _waits import returns

from nao_trainer.tasks.sequence import rules
from nao_trainer.answers.inputs import KeyboardAnswers, PressWindow, TactileAnswers
from nao_trainer.core import mdp, task
from nao_trainer.core.simulation import UserSimulator
from nao_trainer.answers.simulated import SimulatedParticipant, make_mistake
from nao_trainer.ports import TurnContext


def test_window_discards_early_presses_debounces_and_sees_extras():
    """Press times on an injected clock: the rules (debounce, grace) are checked, not the machine's speed."""
    now = [10.0]
    w = PressWindow(debounce_s=0.05, grace_s=0.15, clock=lambda: now[0])
    assert not w.add("A", "A")  # before the window: discarded
    w.open()
    w.add("A", "A", t=10.01)
    w.add("A", "A", t=10.03)  # a bounce (0.02 s < debounce)
    w.add("A", "A", t=10.07)
    w.add("B", "B", t=10.08)
    w.add("C", "C", t=10.12)  # extra press inside the grace period (third press + 0.15 s)
    now[0] = 10.5  # the grace period is over: collect returns at once
    ans = returns(lambda: w.collect(3, timeout_s=2.0))
    assert ans.response == ("A", "A", "B", "C") and not ans.timed_out
    assert w.discarded == 1
    assert ans.reaction_time == pytest.approx(0.01) and ans.completion_time == pytest.approx(0.12)


def test_window_times_out_with_partial_answer():
    w = PressWindow(grace_s=0.0)
    w.open()
    w.add("A", "A")
    t0 = time.monotonic()
    ans = returns(lambda: w.collect(3, timeout_s=0.2))  # ends by its timeout (timed_out says so), never hangs
    assert ans.timed_out and ans.response == ("A",)
    assert time.monotonic() - t0 > 0.15  # it did wait (a lower bound: load only lengthens it)


def test_keyboard_discards_keys_before_the_beep_and_records_invalid_ones():
    r, wfd = os.pipe()
    kb = KeyboardAnswers(fd=r, grace_s=0.1)
    try:
        os.write(wfd, b"ccc")  # typed while the robot spoke
        kb.open_window()
        os.write(wfd, b"a\nB x")
        ans = kb.collect(3, timeout_s=2.0)
        assert [p.key for p in ans.presses] == ["a", "B", "x"]
        assert ans.response == ("A", "B", "?") and [p.letter for p in ans.presses][2] is None
        kb.open_window()
        os.write(wfd, b"ab")
        ans = kb.collect(3, timeout_s=0.3)
        assert ans.timed_out and ans.response == ("A", "B")
    finally:
        kb.close()
        os.close(r)
        os.close(wfd)


def test_an_abandoned_window_collects_nothing_more_and_the_keyboard_reader_stops():
    """A turn interrupted after its beep (robot lost, a refused call): its window closes, presses until the
    next beep are discarded, and the keyboard's reader thread ends (it would read stdin forever)."""
    r, wfd = os.pipe()
    kb = KeyboardAnswers(fd=r, grace_s=0.0)
    try:
        kb.open_window()
        reader = kb._reader
        kb.abandon()
        assert reader is not None and not reader.is_alive() and kb._reader is None
        assert not kb.window.add("a", "A")  # a key pressed during the replay's speech
        os.write(wfd, b"c")
        kb.open_window()  # the replay's beep: what was typed before it is drained
        os.write(wfd, b"ab")
        ans = kb.collect(2, timeout_s=5.0)
        assert ans.response == ("A", "B")
    finally:
        kb.close()
        os.close(r)
        os.close(wfd)


def test_keyboard_survives_end_of_input():
    r, wfd = os.pipe()
    kb = KeyboardAnswers(fd=r, grace_s=0.0)
    os.close(wfd)
    kb.open_window()
    ans = kb.collect(2, timeout_s=0.2)
    kb.close()
    os.close(r)
    assert ans.timed_out and ans.presses == ()


@pytest.fixture()
def standin_robot():
    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    standin = StandIn.start(speed=50)
    robot = NaoqiRobot.connect(standin.url, 5.0, debounce_s=0.01)
    yield standin, robot
    robot.close()
    standin.stop()


def test_head_buttons_over_qi(standin_robot):
    standin, robot = standin_robot
    tactile = TactileAnswers(robot, debounce_s=0.01, grace_s=0.1)
    try:
        standin.press("C")  # before the beep: must not count
        time.sleep(0.1)
        tactile.open_window()
        for letter in "ABA":
            standin.press(letter)
            time.sleep(0.03)  # a person's presses are tens of ms apart; closer ones are bounces
        ans = tactile.collect(3, timeout_s=3.0)
        assert ans.response == ("A", "B", "A") and not ans.timed_out
        assert tactile.window.discarded >= 1
        robot.reconnect(5.0)  # re-subscribes the saved callback: one press still counts once
        tactile.open_window()
        standin.press("B")
        ans = tactile.collect(1, timeout_s=3.0)
        assert ans.response == ("B",)
    finally:
        tactile.close()


class TargetLog:
    """Records what the participant asks a simulated Muse to show (the EEG port's set_target)."""

    def __init__(self):
        self.targets = []

    def set_target(self, e):
        self.targets.append(e)


def sim(p=(1.0, 1.0, 0.0, 0.0)):
    return UserSimulator.from_level_rates("t", p, (0.2, 0.4, 0.6, 0.8), reaction_s=(0.5, 0.6), seconds_per_letter=(0.3, 0.3))


def test_mistakes_always_differ_from_the_sequence():
    rng = np.random.default_rng(3)
    kinds = set()
    for _ in range(300):
        seq = rules.generate_sequence(rng, int(rng.choice(task.LENGTHS)))
        resp, kind = make_mistake(seq, rng)
        kinds.add(kind)
        assert not rules.is_correct(seq, resp)
        assert len(resp) in (len(seq), len(seq) - 1)
    assert kinds == {"substitute", "swap", "omit"}


def test_simulated_participant_direct_answers_follow_the_model():
    log = TargetLog()
    p = SimulatedParticipant(sim(), np.random.default_rng(1), speed=20, monitor=log)
    results = []
    for length in (3, 7):
        state = mdp.encode(length, 0, 0)
        seq = rules.generate_sequence(np.random.default_rng(length), length)
        p.prepare(TurnContext(1, state, length, seq))
        p.open_window()
        ans = p.collect(length, timeout_s=5.0)
        results.append(rules.is_correct(seq, ans.response) and not ans.timed_out)
        times = [x.t for x in ans.presses]
        assert times == sorted(times) and 0.5 / 20 <= times[0] <= 0.6 / 20
    assert results == [True, False]  # level 1 always succeeds, level 3 never
    assert log.targets == [pytest.approx(0.2), pytest.approx(0.6)]


def test_simulated_participant_presses_the_stand_in_buttons(standin_robot):
    standin, robot = standin_robot
    tactile = TactileAnswers(robot, debounce_s=0.01, grace_s=0.05)
    p = SimulatedParticipant(sim(), np.random.default_rng(2), speed=50, press=standin.press, inner=tactile,
                             min_gap_s=1.5)  # 30 ms apart at speed 50, well above the 10 ms debounce
    try:
        seq = ("A", "A", "C", "B", "A")
        p.prepare(TurnContext(1, mdp.encode(5, 0, 0), 5, seq))
        p.open_window()
        ans = p.collect(5, timeout_s=2.0)
        assert ans.response == seq and not ans.timed_out
        pressed = [e["args"][0] for e in standin.transcript() if e["method"] == "press"]
        assert pressed == ["FrontTactilTouched", "FrontTactilTouched", "RearTactilTouched", "MiddleTactilTouched",
                           "FrontTactilTouched"]
    finally:
        p.close()


def test_a_failed_simulated_press_is_a_lost_robot_when_collecting():
    from nao_trainer.ports import RobotConnectionLost

    class Robotless:  # a TactileAnswers stand-in: the presses never reach it
        def __init__(self):
            self.window = PressWindow(0.0, 0.05)

        def open_window(self):
            self.window.open()

        def collect(self, n, timeout_s):
            return self.window.collect(n, timeout_s)

        def close(self):
            self.window.close()

    def press(letter):
        raise RuntimeError("Socket is not connected")

    p = SimulatedParticipant(sim(), np.random.default_rng(2), speed=50, press=press, inner=Robotless())
    p.prepare(TurnContext(1, mdp.encode(3, 0, 0), 3, ("A", "B", "C")))
    p.open_window()
    with pytest.raises(RobotConnectionLost, match="a head-button press failed during the answer window: Socket is not"):
        p.collect(3, timeout_s=0.3)
    p.close()


@pytest.mark.parametrize("speed", [25, 50])
def test_simulated_presses_stay_a_debounce_apart_and_none_is_lost(speed):
    """A late press (a slow qi call, a busy core) must not pull the next one under the debounce interval.

    The debounce is the session's (0.08 s / speed); the presser's own delays are made visible by a
    finger that sometimes lingers after pressing, as a loaded laptop does.
    """
    from nao_trainer.robot.naoqi import NaoqiRobot
    from nao_trainer.robot.standin import StandIn

    debounce = 0.08 / speed
    standin = StandIn.start(speed=speed)
    robot = NaoqiRobot.connect(standin.url, 5.0, debounce_s=debounce)
    tactile = TactileAnswers(robot, debounce_s=debounce, grace_s=0.02)
    jitter = np.random.default_rng(speed)

    def lingering_press(letter):
        standin.press(letter)
        if jitter.random() < 0.5:
            time.sleep(float(jitter.uniform(0.0, 0.025)))

    fast = UserSimulator.from_level_rates("fast", (1.0, 1.0, 1.0, 1.0), reaction_s=(0.05, 0.1),
                                          seconds_per_letter=(0.0, 0.0))
    p = SimulatedParticipant(fast, np.random.default_rng(7), speed=speed, press=lingering_press, inner=tactile,
                             min_gap_s=0.32)
    lost = 0
    try:
        for seed in range(24):
            length = (3, 5, 7, 9)[seed % 4]
            seq = tuple(np.random.default_rng(seed).choice(list("AB"), length).tolist())
            p.prepare(TurnContext(seed, mdp.encode(length, 0, 0), length, seq))
            p.open_window()
            ans = p.collect(length, timeout_s=30.0)  # a hang limit: it returns once every press has arrived
            lost += len(seq) - len(ans.presses)
            same_key = [b.t - a.t for a, b in zip(ans.presses, ans.presses[1:])]
            assert all(gap >= debounce for gap in same_key), same_key
        assert lost == 0
    finally:
        p.close()
        robot.close()
        standin.stop()
