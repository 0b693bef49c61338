"""The session's state table (``STATES``, ``TRANSITIONS``) and its diagram, in one place.

The engine (``session.engine``) drives a ``transitions`` machine built from these tables; the
diagram in ``docs/session-states.md`` is generated from them (a test fails when it is stale).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from nao_trainer.files import PROJECT_ROOT

TURN_STATES = ("select_action", "feedback", "announce", "speak_sequence", "beep", "await_answer", "score", "record")
INTRO_STATES = ("greet", "instructions", "practice")
ACTIVE_STATES = INTRO_STATES + TURN_STATES + ("goodbye",)
STATES: list[str] = [*ACTIVE_STATES, "paused", "aborted", "done"]
TRANSITIONS: list[dict[str, Any]] = [
    {"trigger": "explain", "source": "greet", "dest": "instructions"},
    {"trigger": "practise", "source": "instructions", "dest": "practice"},
    {"trigger": "begin_turns", "source": ["instructions", "practice"], "dest": "select_action"},
    {"trigger": "give_feedback", "source": "select_action", "dest": "feedback"},
    {"trigger": "announce_level", "source": ["select_action", "feedback"], "dest": "announce"},
    {"trigger": "speak", "source": "announce", "dest": "speak_sequence"},
    {"trigger": "sound_beep", "source": "speak_sequence", "dest": "beep"},
    {"trigger": "wait_answer", "source": "beep", "dest": "await_answer"},
    {"trigger": "score_answer", "source": "await_answer", "dest": "score"},
    {"trigger": "record_turn", "source": "score", "dest": "record"},
    {"trigger": "next_turn", "source": "record", "dest": "select_action"},
    {"trigger": "finish_turns", "source": "record", "dest": "goodbye"},
    {"trigger": "end", "source": "goodbye", "dest": "done"},
    {"trigger": "robot_lost", "source": list(ACTIVE_STATES), "dest": "paused"},
    {"trigger": "resume_intro", "source": "paused", "dest": "instructions"},
    {"trigger": "resume_turn", "source": "paused", "dest": "select_action"},
    {"trigger": "resume_goodbye", "source": "paused", "dest": "goodbye"},
    {"trigger": "give_up", "source": "paused", "dest": "aborted"},
    {"trigger": "abort", "source": [*ACTIVE_STATES, "paused"], "dest": "aborted"},
]
FINAL_STATES = ("done", "aborted")
DIAGRAM_PATH = PROJECT_ROOT / "docs" / "session-states.md"

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
        "a test fails when this file is out of date. See docs/session.md for what each state does.\n\n"
        f"```mermaid\n{source}\n```\n"
    )


def export_diagram(path: Path = DIAGRAM_PATH) -> Path:
    """Write the state diagram (``docs/session-states.md``)."""
    path.write_text(diagram_markdown(), encoding="utf-8")
    return path
