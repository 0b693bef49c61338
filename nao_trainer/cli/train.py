"""`nao-trainer train` (placeholder until its issue lands)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("train" if "train" != "import_data" else "import", help="(not yet available)")
    p.set_defaults(func=lambda args: (_ for _ in ()).throw(SystemExit("not yet available")))
