"""MkDocs hooks: the generated reference pages are made from the code at every build (tools/docs_reference.py)."""
from __future__ import annotations

import sys
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(ROOT / "tools") not in sys.path:
    sys.path.insert(0, str(ROOT / "tools"))

import docs_reference  # noqa: E402


def on_files(files, config):  # noqa: D103 (MkDocs's hook signature)
    for name, make in docs_reference.PAGES.items():
        old = files.get_file_from_path(name)
        if old is not None:
            files.remove(old)
        files.append(File.generated(config, name, content=make()))
    # Figures the commands write outside docs/ (train's figures in sim/policies/), served as they are.
    for png in sorted((ROOT / "sim" / "policies").glob("*.png")):
        files.append(File.generated(config, f"figures/sim-policies/{png.name}", abs_src_path=str(png)))
    return files
