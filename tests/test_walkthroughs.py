"""Every walkthrough runs as written (issue 29): each shell block marked `<!-- runnable -->` in the tutorials and
how-to guides runs in a fresh copy of the repository's data folders, with the shared data beside it
(../shared, as in a checkout), on the stand-in, the simulated participant and the simulated Muse.

One substitution, for speed: the pages' `tar -xJf .../X.tar.xz -C DIR` is the run's one extraction of that archive
(the same command, made by tests/conftest.py for every test that reads the data: about 6 s of CPU for the bands) and
each block links the result into its DIR. Linked, not copied: the blocks' dataset roots are then one folder, so its
import (keyed by the root's real path, about 3 s of CPU) is paid once per run, not by each block that reads the data.
The pages read the data and write nothing into it."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
MARK = "<!-- runnable -->"


def runnable_blocks() -> list[tuple[str, str]]:
    """(page:index, script) for each ```bash block right after a runnable marker."""
    blocks = []
    for page in sorted([*(ROOT / "docs" / "tutorials").glob("*.md"), *(ROOT / "docs" / "how-to").glob("*.md")]):
        text = page.read_text()
        for i, match in enumerate(re.finditer(re.escape(MARK) + r"\s*\n```(?:bash|sh|console)?\n(.*?)\n```", text, re.S)):
            blocks.append((f"{page.relative_to(ROOT / 'docs')}:{i + 1}", match.group(1)))
        assert text.count(MARK) == len([b for b in blocks if b[0].startswith(str(page.relative_to(ROOT / "docs")))]), \
            f"{page}: a runnable marker not followed by a shell block"
    return blocks


def test_walkthroughs_have_runnable_blocks():
    names = {name.split(":")[0] for name, _ in runnable_blocks()}
    assert {"tutorials/first-session.md", "tutorials/first-pilot.md", "tutorials/first-real-nao.md",
            "tutorials/first-study.md", "how-to/power.md", "how-to/amend-protocol.md", "how-to/published-data.md",
            "how-to/rehearse-with-stand-in.md"} <= names, names


def _sandbox(where: Path) -> Path:
    """A checkout's layout: repo/ with its data folders (config copied: pages write into it), ../shared beside it."""
    repo = where / "repo"
    repo.mkdir(parents=True)
    shutil.copytree(ROOT / "config", repo / "config")
    for name in ("sim", "dialogue", "behaviors"):
        (repo / name).symlink_to(ROOT / name)
    shared = Path(os.environ.get("NAO_TRAINER_SHARED", ROOT.parent / "shared"))
    (where / "shared").symlink_to(shared)
    return repo


TAR = re.compile(r"tar -xJf (\S+\.tar\.xz) -C ([\w./~-]+)")


def _extracted(script: str, archives: dict[str, Path], repo: Path) -> str:
    """``script`` with each ``tar -xJf ARCHIVE -C DIR`` replaced by links to the run's extraction of ARCHIVE."""
    def link(match: re.Match) -> str:
        archive = (repo / match.group(1)).resolve()
        assert archive.exists(), f"a page extracts {match.group(1)}, which is not in ../shared"
        assert archive.name in archives, f"a page extracts {archive.name}: add its fixture to archives() here"
        return f"ln -s {archives[archive.name]}/* {match.group(2)}/"
    return TAR.sub(link, script)


def _run(name: str, script: str, where: Path, archives: dict[str, Path]) -> tuple[str, int, str]:
    repo = _sandbox(where)
    script = _extracted(script, archives, repo)
    env = dict(os.environ, PYTHONPATH=str(ROOT), PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
               NAO_TRAINER_SHARED=str(where / "shared"), NAO_TRAINER_KEYS=str(where / "keys"))
    done = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=repo, env=env, capture_output=True,
                          text=True, timeout=600)
    return name, done.returncode, (done.stdout + done.stderr)[-3000:]


@pytest.fixture
def archives(dataset_root, raw_root) -> dict[str, Path]:
    """The run's extraction of each archive the pages may extract: the folder its ``tar -C`` would fill."""
    return {"clean_data_bands.tar.xz": dataset_root.parent, "raw_sessions.tar.xz": raw_root.parent}


@pytest.mark.slow
def test_every_runnable_block_runs_as_written(tmp_path, archives):
    blocks = runnable_blocks()
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda nb: _run(nb[0], nb[1], tmp_path / re.sub(r"\W", "_", nb[0]), archives),
                                blocks))
    failed = [f"{name} exited {rc}:\n{out}" for name, rc, out in results if rc != 0]
    assert not failed, "\n\n".join(failed)
