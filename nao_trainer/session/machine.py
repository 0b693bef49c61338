"""The session's state table (``STATES``, ``TRANSITIONS``) and its diagram, in one place.

The engine (``session.engine``) drives a ``transitions`` machine built from these tables; the
diagram in ``docs/reference/session-states.md`` is generated from them (a test fails when it is stale).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from nao_trainer.files import PROJECT_ROOT

#: A turn's states, task-neutral: the task (``nao_trainer.tasks``) decides what each one presents or asks.
#: ``present`` plays the trial (the sequence task speaks its letters), ``open_window`` opens the answer window
#: (a beep), ``collect`` waits for the answer, ``judge`` judges and scores it, ``record`` writes the row.
TURN_STATES = ("select_action", "feedback", "announce", "present", "open_window", "collect", "judge", "record")
INTRO_STATES = ("greet", "instructions", "practice")
ACTIVE_STATES = INTRO_STATES + TURN_STATES + ("goodbye",)
#: Groups are named, never sliced by position: inserting a state changes no group silently (a test checks
#: every turn state is in exactly the groups listed here).
#: A turn is in flight in these states (it has been chosen and not yet recorded).
IN_TURN = ("feedback", "announce", "present", "open_window", "collect", "judge", "record")
#: A turn in flight can be played again from these (not once its answer is judged: it is recorded first).
REPLAYABLE = ("feedback", "announce", "present", "open_window", "collect")
#: Played again after a call refused by a robot that was then set back (``engine.Session._set_back``).
AGAIN_STATES = (*INTRO_STATES, "goodbye")
#: ``paused``: the robot was lost; ``operator_pause``: the operator paused (robot idle, EEG recording).
STATES: list[str] = [*ACTIVE_STATES, "paused", "operator_pause", "aborted", "done"]
#: Where pause, stop and repeat act. Not in judge/record: an answer already given is recorded first
#: (the engine holds those commands until the next turn begins).
INTERRUPTIBLE = (*INTRO_STATES, "select_action", "feedback", "announce", "present", "open_window", "collect")
_PLAYING = [*INTRO_STATES, *TURN_STATES]
TRANSITIONS: list[dict[str, Any]] = [
    {"trigger": "explain", "source": "greet", "dest": "instructions"},
    {"trigger": "practise", "source": "instructions", "dest": "practice"},
    {"trigger": "begin_turns", "source": ["instructions", "practice"], "dest": "select_action"},
    {"trigger": "give_feedback", "source": "select_action", "dest": "feedback"},
    {"trigger": "announce_level", "source": ["select_action", "feedback"], "dest": "announce"},
    {"trigger": "speak", "source": "announce", "dest": "present"},
    {"trigger": "sound_beep", "source": "present", "dest": "open_window"},
    {"trigger": "wait_answer", "source": "open_window", "dest": "collect"},
    {"trigger": "score_answer", "source": "collect", "dest": "judge"},
    {"trigger": "record_turn", "source": "judge", "dest": "record"},
    # A task whose answers come while it presents (n-back): the window opens first, then the stream.
    {"trigger": "open_first", "source": "announce", "dest": "open_window"},
    {"trigger": "present_in_window", "source": "open_window", "dest": "present"},
    {"trigger": "collect_presented", "source": "present", "dest": "collect"},
    {"trigger": "next_turn", "source": "record", "dest": "select_action"},
    {"trigger": "finish_turns", "source": "record", "dest": "goodbye"},
    {"trigger": "end", "source": "goodbye", "dest": "done"},
    {"trigger": "robot_lost", "source": list(ACTIVE_STATES), "dest": "paused"},
    # A call refused mid-turn by a NAO put to sleep or whose Autonomous Life changed: set back, turn replayed.
    {"trigger": "robot_recovered", "source": list(REPLAYABLE), "dest": "select_action"},
    {"trigger": "resume_intro", "source": ["paused", "operator_pause"], "dest": "instructions"},
    {"trigger": "resume_turn", "source": ["paused", "operator_pause"], "dest": "select_action"},
    {"trigger": "resume_goodbye", "source": "paused", "dest": "goodbye"},
    {"trigger": "give_up", "source": "paused", "dest": "aborted"},
    {"trigger": "abort", "source": [*ACTIVE_STATES, "paused", "operator_pause"], "dest": "aborted"},
    # Operator commands (session.engine drains them between states; see docs/how-to/session.md).
    # From ``paused`` (the robot away): an operator pause taken while it was away holds once it is back.
    {"trigger": "pause", "source": [*INTERRUPTIBLE, "paused"], "dest": "operator_pause"},
    {"trigger": "operator_stop", "source": [*INTERRUPTIBLE, "operator_pause"], "dest": "goodbye"},
    {"trigger": "time_up", "source": ["select_action", "operator_pause"], "dest": "goodbye"},
    {"trigger": "repeat_turn", "source": list(REPLAYABLE), "dest": "select_action"},
    {"trigger": "repeat_last", "source": "select_action", "dest": None},
    {"trigger": "override_next", "source": [*_PLAYING, "operator_pause"], "dest": None},
    {"trigger": "mark_invalid", "source": list(IN_TURN), "dest": None},
    {"trigger": "add_note", "source": [*ACTIVE_STATES, "paused", "operator_pause"], "dest": None},
    # A resumed session (``run --resume``) goes straight to the next turn.
    {"trigger": "resume_session", "source": "greet", "dest": "select_action"},
]
#: Which trigger each operator command fires (``repeat``: mid-turn ``repeat_turn``, between turns ``repeat_last``).
COMMAND_TRIGGERS: dict[str, tuple[str, ...]] = {
    "pause": ("pause",), "resume": ("resume_turn", "resume_intro"), "stop": ("operator_stop",),
    "override": ("override_next",), "repeat": ("repeat_turn", "repeat_last"), "invalid": ("mark_invalid",),
    "note": ("add_note",),
}
FINAL_STATES = ("done", "aborted")
DIAGRAM_PATH = PROJECT_ROOT / "docs" / "reference" / "session-states.md"

def diagram_markdown() -> str:
    """The state diagram as a Markdown page with a Mermaid block (no graphviz needed)."""
    from transitions.extensions import GraphMachine

    class _Model:
        pass

    model = _Model()
    GraphMachine(model=model, states=STATES, transitions=TRANSITIONS, initial="greet", auto_transitions=False,
                 graph_engine="mermaid", title="nao-trainer session")
    # Keep the plain diagram: drop transitions' title front matter and colour classes (the
    # "active state" colouring means nothing in a document).
    lines = model.get_graph().source.strip().splitlines()
    body = lines[lines.index("stateDiagram-v2"):]
    source = "\n".join(ln for ln in body if ln.strip() and not ln.strip().startswith(("classDef", "Class ")))
    return (
        "# Session states\n\n"
        "Generated from `nao_trainer.session.machine.STATES` / `TRANSITIONS` by `nao_trainer.session.machine.export_diagram()`;\n"
        "a test fails when this file is out of date. See docs/how-to/session.md for what each state does.\n\n"
        f"```mermaid\n{source}\n```\n"
    )


def export_diagram(path: Path = DIAGRAM_PATH) -> Path:
    """Write the state diagram (``docs/reference/session-states.md``)."""
    path.write_text(diagram_markdown(), encoding="utf-8")
    return path
