"""Auditory n-back on the head buttons as a ``tasks.base.Task`` (issue 26 item 3).

The robot says "Level N", beeps (the answer window opens), then speaks a block of ``20 + n`` consonants, one every
3 s (session seconds); the participant presses the front head button when the letter is the one ``n`` back. A
block is one turn: its outcome is hits, misses, false alarms and correct rejections, d′ with the log-linear
correction, and success = fewer than 3 errors (Jaeggi et al. 2008's level-up rule). Levels 1..4 are n = 1..4.
Sources of every parameter: ``tasks.nback.rules`` and docs/explanation/tasks.md.

The simulated participant is an equal-variance signal-detection observer per level (``Settings.d_prime``,
``Settings.criterion``); it presses the stand-in's front button over qi like the sequence task's participant.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from nao_trainer.core import task as levels
from nao_trainer.core.settings import setting, settings
from nao_trainer.ports import Answer
from nao_trainer.tasks.base import COMMON_COLUMNS, Judgement, Presenter, Trial
from nao_trainer.tasks.nback import rules

#: The n-back task's own turns.csv columns (after the common ones).
OWN_COLUMNS: tuple[str, ...] = ("n", "stimuli", "targets", "hits", "misses", "false_alarms", "correct_rejections",
                                "d_prime")
COLUMNS: tuple[str, ...] = COMMON_COLUMNS[:7] + OWN_COLUMNS + COMMON_COLUMNS[7:]


def _four_numbers(value: Any) -> str | None:
    if not isinstance(value, list) or len(value) != 4 or not all(isinstance(v, (int, float)) for v in value):
        return f"must be a list of 4 numbers (levels n = 1..4), got {value!r}"
    return None


@settings
class NBackSettings:
    """The n-back task's own keys (``task.settings``)."""

    targets: int = setting(rules.TARGETS, kind=int, min=1, max=20, doc="targets per block (Jaeggi et al. 2008: 6)")
    fillers: int = setting(rules.FILLERS, kind=int, min=8, max=60,
                           doc="a block is fillers + n stimuli (Jaeggi et al. 2008: 20)")
    soa_s: float = setting(rules.SOA_S, kind=float, min=0.5, max=10.0,
                           doc="seconds from one stimulus to the next (Jaeggi et al. 2008: 3)")
    # The simulated participant (signal detection per level). Assumed values: d′ falling with load inside the range
    # n-back studies report (docs/explanation/tasks.md says where they come from and that they are not one study's table).
    d_prime: list = setting(factory=lambda: [3.2, 2.6, 1.9, 1.3], kind=list, check=_four_numbers,
                            doc="simulated participant: d′ at n = 1..4")
    criterion: list = setting(factory=lambda: [0.4, 0.4, 0.3, 0.2], kind=list, check=_four_numbers,
                              doc="simulated participant: criterion c at n = 1..4 (c > 0: conservative)")


#: ``evaluate --task nback``'s population: the default observer's d′ at every level scaled by these abilities
#: (criteria kept). An assumption of ours, not a fitted spread: the published data are the sequence task's.
ABILITIES: tuple[float, ...] = (0.6, 0.8, 1.0, 1.2, 1.4, 1.6)


class NBackTask:
    """Auditory n-back, levels n = 1..4 (see the module docstring)."""

    name: ClassVar[str] = "nback"
    levels: ClassVar[tuple[int, ...]] = levels.LEVELS
    columns: ClassVar[tuple[str, ...]] = COLUMNS
    dialogue_events: ClassVar[Mapping[str, frozenset[str]]] = {}
    answer_letters: ClassVar[tuple[str, ...]] = (rules.MATCH_BUTTON,)
    #: The answer window opens (the beep) before the stream: presses come while the robot speaks.
    presents_in_window: ClassVar[bool] = True
    Settings: ClassVar[type] = NBackSettings
    #: Its own words (instructions, practice) for a study that keeps the shipped dialogue.
    dialogue_file: ClassVar[Path] = Path(__file__).parent / "en.yaml"

    #: The console's turn table: the block's load and its signal-detection outcome.
    table_fields: ClassVar[Mapping[str, str]] = {"n": "n", "hits": "hits", "misses": "misses",
                                                 "false_alarms": "false alarms", "d_prime": "d′"}
    #: BIDS: the task label, its description and its columns (``study export --bids``).
    bids_name: ClassVar[str] = "nback"
    description: ClassVar[str] = ("auditory n-back with a NAO robot: a block of 20 + n spoken letters, one every 3 s; "
                                  "press the front head button when a letter matches the one n back (Jaeggi et al. "
                                  "2008, PNAS 105, 6829)")
    column_docs: ClassVar[Mapping[str, tuple[str, str | None]]] = {
        "level": ("difficulty level 1-4: the load n of the n-back block", None),
        "response": ("the buttons pressed during the block (A: the front head button, the match button)", None),
        "success": ("True when the block had fewer than 3 errors (misses + false alarms; Jaeggi et al. 2008)", None),
        "reaction_time": ("time from the beep before the block to the first press", "s"),
        "completion_time": ("time from the beep before the block to the last press", "s"),
        "n": ("the load n: a target is a letter equal to the one n before it", None),
        "stimuli": ("the letters the robot said, in order", None),
        "targets": ("per letter, 1 when it was a target (equal to the one n back), else 0", None),
        "hits": ("targets pressed", None),
        "misses": ("targets not pressed", None),
        "false_alarms": ("non-targets pressed", None),
        "correct_rejections": ("non-targets not pressed", None),
        "d_prime": ("z(H) - z(F) with the log-linear correction (Hautus 1995)", None),
    }

    def __init__(self, settings: NBackSettings | None = None) -> None:
        self.settings = settings or NBackSettings()

    def make_trial(self, level: int, rng: np.random.Generator) -> Trial:
        levels.length_of(level)  # validates the level
        s = self.settings
        stream, targets = rules.make_stream(rng, level, s.targets, s.fillers)
        expected = tuple(rules.MATCH_BUTTON for t in targets if t)
        return Trial(level, stream, expected, None, {"n": level, "targets": targets, "onsets": []})

    def practice_trial(self, rng: np.random.Generator) -> Trial:
        return self.make_trial(1, rng)

    def size(self, trial: Trial) -> int:
        return int(trial.data["n"])  # "Level N" announces n

    def present(self, stage: Presenter, trial: Trial, turn: int, onset: float | None = None) -> None:
        """Each letter on the SOA grid from the window's opening; the actual onsets (seconds after the beep) are
        kept for judging, and each stimulus is an EEG/XDF marker."""
        assert onset is not None  # presents_in_window: the engine opened the window first
        trial.data["onsets"][:] = stage.stream(trial.stimuli, self.settings.soa_s, onset, turn,
                                               targets=trial.data["targets"])

    def response_timeout_s(self, trial: Trial, base_s: float, per_item_s: float) -> float:
        """The stream and one more interval for the last letter's answer (from the beep, session seconds)."""
        return float(self.settings.soa_s * (len(trial.stimuli) + 1))

    def outcome(self, trial: Trial, answer: Answer, soa_wall_s: float | None = None) -> rules.Outcome:
        onsets = tuple(trial.data["onsets"])
        window = soa_wall_s if soa_wall_s is not None else (
            (onsets[-1] - onsets[0]) / max(1, len(onsets) - 1) if len(onsets) > 1 else float("inf"))
        times = tuple(p.t for p in answer.presses if p.letter == rules.MATCH_BUTTON)
        return rules.judge(trial.data["targets"], rules.responded(onsets, window, times), trial.data["n"])

    def judge(self, trial: Trial, answer: Answer) -> Judgement:
        out = self.outcome(trial, answer)
        notes = [f"{out.errors} errors (misses {out.misses}, false alarms {out.false_alarms})"] if not out.success else []
        notes += [f"other button {p.key!r}" for p in answer.presses if p.letter != rules.MATCH_BUTTON]
        fields = {"n": trial.data["n"], "stimuli": "".join(trial.stimuli),
                  "targets": "".join("1" if t else "0" for t in trial.data["targets"]), "hits": out.hits,
                  "misses": out.misses, "false_alarms": out.false_alarms, "correct_rejections": out.correct_rejections,
                  "d_prime": round(out.d_prime, 3)}
        return Judgement(out.success, tuple(notes), fields)

    def score(self, level: int, success: bool) -> int:
        return levels.score(level, success)  # the MDP's reward, equation (1): +n on success, -1 on failure

    def signed_score(self, level: int, success: bool) -> int:
        return levels.signed_score(level, success)

    def row_problem(self, row: dict[str, str]) -> str | None:
        """Why a recorded block's fields disagree (``run --resume`` checks turns.csv): n is the level, the stream
        is 20 + n letters (the settings'), the counts add up to its targets and letters, and the success is
        the criterion's."""
        try:
            n, hits, misses = int(row["n"]), int(row["hits"]), int(row["misses"])
            fas, crs = int(row["false_alarms"]), int(row["correct_rejections"])
        except (TypeError, ValueError, KeyError):
            return "n, hits, misses, false_alarms and correct_rejections must be integers"
        stimuli, targets = row.get("stimuli") or "", row.get("targets") or ""
        if n != int(row["level"]) or len(stimuli) != rules.block_length(n, self.settings.fillers):
            return f"n {n}, level {row['level']} and a stream of {len(stimuli)} letters do not agree"
        if len(targets) != len(stimuli) or set(targets) - {"0", "1"} or hits + misses != targets.count("1") \
                or hits + misses + fas + crs != len(stimuli):
            return f"hits {hits}, misses {misses}, false alarms {fas} and correct rejections {crs} do not add up to " \
                   f"the stream's targets {targets!r}"
        if (row["success"] == "True") != rules.Outcome(hits, misses, fas, crs).success:
            return f"success {row['success']} with {misses + fas} errors (fewer than 3 is a success)"
        return None

    def describe(self, row: dict[str, Any]) -> str:
        """The progress line's middle: hits of the targets, false alarms."""
        return f"hits {row['hits']}/{row['targets'].count('1')} false alarms {row['false_alarms']}"

    def span(self, rows: list[dict[str, Any]]) -> str | None:
        """Mean d′ per level played (the n-back's capacity line)."""
        by: dict[int, list[float]] = {}
        for r in rows:
            if r.get("d_prime") not in (None, ""):
                by.setdefault(int(r["level"]), []).append(float(r["d_prime"]))
        if not by:
            return None
        return "d′ by level: " + "  ".join(f"{n}-back {np.mean(v):.2f} ({len(v)})" for n, v in sorted(by.items()))

    # -- the simulated participant -------------------------------------------------------------------------------

    def level_success(self) -> tuple[float, ...]:
        """P(a block succeeds) at n = 1..4 for the simulated observer (exact, ``rules.success_probability``)."""
        s = self.settings
        return tuple(rules.success_probability(d, c, n, s.targets, s.fillers)
                     for n, d, c in zip(self.levels, s.d_prime, s.criterion))

    def simulated_users(self) -> tuple[tuple[str, tuple[float, ...]], ...]:
        """(name, P(block succeeds) at each of ``levels``) of the evaluation's observers (``ABILITIES``)."""
        s = self.settings
        return tuple((f"nback-d{a:g}x", tuple(rules.success_probability(a * d, c, n, s.targets, s.fillers)
                                               for n, d, c in zip(self.levels, s.d_prime, s.criterion)))
                     for a in ABILITIES)

    def simulated_answer(self, trial: Trial, rng: np.random.Generator,
                         reaction_s: float) -> tuple[bool, tuple[str, ...], tuple[float, ...], str]:
        """What the signal-detection observer presses: (intended success, letters, times from the beep, note).

        Each target is pressed with P(hit), each non-target with P(false alarm), ``reaction_s`` after the
        stimulus's scheduled onset (the answer window's first interval starts at the beep)."""
        n = trial.data["n"]
        s = self.settings
        h, f = rules.rates(float(s.d_prime[n - 1]), float(s.criterion[n - 1]))
        draws = rng.random(len(trial.stimuli))
        pressed = tuple(bool(d < (h if t else f)) for d, t in zip(draws, trial.data["targets"]))
        out = rules.judge(trial.data["targets"], pressed, n)
        times = tuple((i + 1) * s.soa_s + reaction_s for i, p in enumerate(pressed) if p)
        return out.success, tuple(rules.MATCH_BUTTON for _ in times), times, f"{out.errors} errors planned"
