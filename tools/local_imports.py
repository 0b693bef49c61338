"""The function-local imports of package modules in nao_trainer/, each with the reason it is not at the top.

    python tools/local_imports.py          # one line per import statement: site, target, reason
    python tools/local_imports.py --count  # the totals by reason

A reason is worked out from the code, not written by hand, for every site it can be:

``cycle``   the imported module reaches the importing one through module-level imports, so a top-level
            import would be circular;
``loads``   a top-level import would load third-party packages (``HEAVY``) into a module that loads
            none of them: ``nao-trainer --help``, a one-line error and the commands that need no robot,
            no EEG and no statistics stay quick (each process of the test suite pays it too);
``extra``   it sits in a ``try`` whose ``except ImportError`` refuses in one line: the module needs an
            optional extra (``setup.py``'s ``extras_require``) that an install may lack;
``stated``  one of ``STATED`` below, with its reason in words.

``tests/test_layers.py`` fails on a site with none of the three: such an import belongs at the top.
"""
from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "nao_trainer"

#: Third-party packages whose import costs tens of milliseconds or more, or pulls in a native runtime
#: (qi starts its own threads; pylsl must load after LSL's configuration is chosen).
HEAVY = frozenset({"numpy", "scipy", "qi", "pylsl", "sklearn", "statsmodels", "matplotlib", "mne", "mne_bids",
                   "numba", "brainflow", "starlette", "uvicorn", "sqlalchemy", "alembic", "psycopg", "psycopg2",
                   "dask", "distributed", "joblib", "pyxdf", "questplus", "pandas", "cryptography", "transitions",
                   "playwright", "muselsl", "requests"})

#: (importing module, imported module) -> why the import waits, where the code cannot show it.
STATED: dict[tuple[str, str], str] = {}


@dataclass(frozen=True)
class Site:
    path: str  # nao_trainer/x/y.py:LINE
    module: str
    target: str
    reason: str  # "" when none


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__" and len(parts) > 1:
        parts.pop()
    return ".".join(parts)


@lru_cache(maxsize=None)
def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def targets(name: str, path: Path, node: ast.Import | ast.ImportFrom) -> list[str]:
    """Package modules and third-party top-level names an import statement names."""
    known = modules()
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            package = name if path.name == "__init__.py" else name.rpartition(".")[0]
            anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
            base = ".".join(anchor + ([base] if base else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
    out = []
    for t in names:
        if t.startswith("nao_trainer"):
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t:
                out.append(t)
        else:
            out.append(t.split(".")[0])
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _guarded(node: ast.Try) -> bool:
    """A ``try: import x`` / ``except ImportError`` (an optional extra): not a module-level requirement."""
    return any(isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
               for h in node.handlers)


@lru_cache(maxsize=None)
def _parsed(name: str) -> tuple[frozenset[str], frozenset[str], tuple[tuple[int, str, bool], ...]]:
    """(package modules imported at module level, third-party names imported at module level,
    function-local import statements of package modules as (line, first target, guarded by ImportError))."""
    path = modules()[name]
    top_pkg: set[str] = set()
    top_ext: set[str] = set()
    local: list[tuple[int, str, bool]] = []

    def walk(node: ast.AST, in_function: bool, guarded: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                continue
            if isinstance(child, ast.Try) and _guarded(child) and not in_function:
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found = targets(name, path, child)
                if in_function:
                    mine = [t for t in found if t.startswith("nao_trainer")]
                    if mine:
                        local.append((child.lineno, mine[0], guarded))
                else:
                    for t in found:
                        (top_pkg if t.startswith("nao_trainer") else top_ext).add(t)
            walk(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)),
                 guarded or (in_function and isinstance(child, ast.Try) and _guarded(child)))

    walk(ast.parse(path.read_text(encoding="utf-8"), str(path)), False, False)
    return frozenset(top_pkg), frozenset(top_ext), tuple(local)


def _with_parents(name: str) -> list[str]:
    """A module and the packages Python runs first to import it (``a.b.c``: ``a``, ``a.b``, ``a.b.c``)."""
    parts = name.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts)) if ".".join(parts[: i + 1]) in modules()]


@lru_cache(maxsize=None)
def closure(name: str) -> frozenset[str]:
    """Every package module that importing ``name`` runs at module level."""
    seen: set[str] = set()
    todo = _with_parents(name)
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        for t in _parsed(m)[0]:
            todo.extend(_with_parents(t))
    return frozenset(seen)


def heavy_loaded(name: str) -> frozenset[str]:
    """The ``HEAVY`` packages importing ``name`` loads at module level."""
    return frozenset(e for m in closure(name) for e in _parsed(m)[1] if e in HEAVY)


def sites() -> list[Site]:
    out = []
    for name, path in modules().items():
        for line, target, guarded in _parsed(name)[2]:
            where = f"{path.relative_to(PACKAGE.parent)}:{line}"
            if name in closure(target):
                reason = f"cycle: {target} imports {name} at module level"
            elif added := sorted(heavy_loaded(target) - heavy_loaded(name)):
                reason = f"loads {', '.join(added)}"
            elif guarded:
                reason = "extra: an optional extra, refused in one line when missing"
            elif (name, target) in STATED:
                reason = f"stated: {STATED[name, target]}"
            else:
                reason = ""
            out.append(Site(where, name, target, reason))
    return out


def main(argv: list[str]) -> int:
    found = sites()
    if "--count" in argv:
        kinds: dict[str, int] = {}
        for s in found:
            kind = s.reason.split(":")[0].split(" ")[0] or "NONE"
            kinds[kind] = kinds.get(kind, 0) + 1
        print(f"{len(found)} function-local imports of package modules: "
              + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))
        return 0
    for s in found:
        print(f"{s.path:48} {s.target:40} {s.reason or 'NO REASON: import it at the top'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
