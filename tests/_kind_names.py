"""Issue 26: no kind string is compared outside its registry: the walk ``tests/test_layers.py`` runs.

A plug-in (task, policy, EEG device, robot model) is registered by name in ``nao_trainer.registry`` and lives
in one home: the folder of its entry point's module (``tasks/sequence/``, ``policies/``, ``eeg/devices/``,
``robot/models/``). Anywhere else, code asks the plug-in (an attribute or method it declares, a registry
lookup, the setting's declared default) and never branches on its name. The walk below reads every module
of the package (the module list and parse of ``tests/test_layers.py``) and the names from the registry itself, and
reports, outside the registry module and outside the name's own home:

*comparisons*: ``x == "name"`` / ``!=`` / ``is``, ``x in ("name", ...)`` (a literal tuple, list, set or dict,
or a module-level one, also one imported from another package module), ``x.startswith("name")``,
``case "name":``, argparse's ``choices=(...)``, and a literal table keyed by names looked up with
``TABLE[x]`` / ``TABLE.get(x)``; a word matches a name also as a spec, ``name:argument``. A kind is a value
(``config.robot.model``, ``task.name``), so ``"word" in row`` and ``row["word"]``, which ask whether a row or
a mapping holds a key (a turns.csv column such as ``sequence``), are not comparisons;

*picks*: a name chosen in the code instead of asked for: ``registry.spec/load/make(kind, "name")`` or a
function that passes its parameter to them (``make_device("muse")``), ``x if c else "name"``,
``x or "name"``, ``default="name"``, and a literal table whose values are names looked up with ``[x]`` /
``.get(x)``.

Two rules keep words that merely coincide with a name out, each stated here, none a list of lines:

* **Another vocabulary.** Types are unknown to a walk, so a comparison is judged by its alternatives: the
  words one expression is compared with inside one function (or at module level). If any of them is no
  registered name, the expression is a vocabulary of its own that shares a word with a kind: NAOqi's
  speaking modes (``disabled``, ``random``, ``contextual``), the evaluation's strategies
  (``fixed:N``, ``best-fixed``, ``random``, ``oracle``, ``staircase``, ``usp``, ``usp-learning``: the
  offline comparison's own names, parsed once in ``experiments/comparison.py``, not the live policy
  plug-ins), the personalisation pipelines (``paper``, ``posterior-ev``, ``personalised``).
* **Stand-ins of hardware** (``STANDINS``): they play the device a plug-in drives, on the device's side of
  the wire, and know the robots they can play by name, as a lab's own stand-in would; the plug-in is what
  they check, so they cannot ask it.

Not seen (a walk of literals): a name held in a local variable or built in an f-string, a list that mixes a
kind's names with a word no plug-in is registered under (taken for another vocabulary), a branch on a
plug-in's class (``isinstance``) or an import of its home, and files that are not Python.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from nao_trainer import registry

#: Folders that stand in for hardware, with the reason they stay outside the rule (printed by the test).
STANDINS: dict[str, str] = {
    "nao_trainer/robot/standin": "the NAO stand-in plays the robot's side of NAOqi: its tables are the bodies it "
                                 "can play (postures, body types) as the real robot answers, what a robot-model "
                                 "plug-in is checked against",
}
#: The registry's functions that pick a plug-in by name: (kind, name, ...).
PICKERS = frozenset({"spec", "load", "make"})
COLLECTIONS = (ast.Tuple, ast.List, ast.Set, ast.Dict)
#: The nodes the rule looks at.
LOOKED_AT = (ast.Compare, ast.Match, ast.Call, ast.Subscript, ast.IfExp, ast.BoolOp)


@dataclass(frozen=True)
class Hit:
    where: str  # nao_trainer/x/y.py:LINE
    name: str
    code: str  # shortened

    def __str__(self) -> str:
        return f"{self.where}: {self.name!r}: {self.code}"


@dataclass(frozen=True)
class Registered:
    """The registered names of every kind, each with the homes (folders, relative to the package's parent)
    where it may be written: name -> homes."""

    homes: dict[str, tuple[str, ...]]

    @classmethod
    def read(cls, mods: dict[str, Path], root: Path) -> "Registered":
        """From the registry, every group: the plug-ins whose entry point is a module of the package (``mods``);
        a home is the folder of that module. The names of other distributions' plug-ins (and of those a test
        registers for a while) are unknown to the package, so it cannot compare them."""
        homes: dict[str, list[str]] = {}
        for kind in registry.GROUPS:
            for found in registry.specs(kind):
                path = mods.get(found.entry_point.partition(":")[0])
                if path is not None:
                    homes.setdefault(found.name, []).append(path.parent.relative_to(root).as_posix())
        return cls({name: tuple(h) for name, h in homes.items()})

    def name_of(self, word: str) -> str | None:
        """The registered name ``word`` is (``usp``) or specifies (``usp:cluster``), else None."""
        for candidate in (word, word.partition(":")[0]):
            if candidate in self.homes:
                return candidate
        return None

    def at_home(self, name: str, rel: str) -> bool:
        return any(rel == h or rel.startswith(h + "/") for h in self.homes[name])


def _literal(node: ast.AST | None) -> ast.AST | None:
    """``frozenset({...})`` and the like: the literal inside."""
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) == 1
            and node.func.id in ("frozenset", "set", "tuple", "list", "dict")):
        return node.args[0]
    return node


def _is_str(node: ast.AST | None) -> bool:
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _callee(call: ast.Call) -> str:
    f = call.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""


def _picks_kind(call: ast.Call) -> bool:
    """``registry.spec/load/make("<kind>", name, ...)``."""
    return (_callee(call) in PICKERS and len(call.args) >= 2 and _is_str(call.args[0])
            and call.args[0].value in registry.GROUPS)


class _Module:
    """One module's tree, read in one pass: its module-level literals (``NAME = "x"``, ``NAME = (...)``), the
    names it imports from package modules, the functions that pass a parameter of theirs to a registry pick
    (``make_model(name)``), and the nodes the rule looks at, each with its scope (the enclosing function)."""

    def __init__(self, tree: ast.Module, known: set[str]) -> None:
        self.literals: dict[str, ast.AST] = {}
        for node in tree.body:
            target, value = ((node.targets[0], node.value) if isinstance(node, ast.Assign) and len(node.targets) == 1
                             else (node.target, node.value) if isinstance(node, ast.AnnAssign) else (None, None))
            value = _literal(value)
            if isinstance(target, ast.Name) and (isinstance(value, COLLECTIONS) or _is_str(value)):
                self.literals[target.id] = value
        self.known = known
        self.imported: dict[str, tuple[str, str]] = {}  # local name -> (package module, attribute or "")
        self.wrappers: dict[str, int] = {}  # function -> position of the parameter it picks a plug-in by
        self.nodes: list[tuple[str, ast.AST]] = []
        self.others: dict[str, _Module] = {}
        self._visit(tree, "", None)

    def _visit(self, node: ast.AST, scope: str, fn: ast.FunctionDef | ast.AsyncFunctionDef | None) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ImportFrom) and child.module and not child.level:
                for alias in child.names:
                    full = f"{child.module}.{alias.name}"
                    self.imported[alias.asname or alias.name] = ((full, "") if full in self.known
                                                                 else (child.module, alias.name))
            elif isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.asname:
                        self.imported[alias.asname] = (alias.name, "")
            elif isinstance(child, LOOKED_AT):
                self.nodes.append((scope, child))
                if fn is not None and isinstance(child, ast.Call) and _picks_kind(child) \
                        and isinstance(child.args[1], ast.Name):
                    params = [a.arg for a in fn.args.posonlyargs + fn.args.args]
                    if params[:1] in (["self"], ["cls"]):
                        params = params[1:]
                    if child.args[1].id in params:
                        self.wrappers[fn.name] = params.index(child.args[1].id)
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                self._visit(child, f"{scope}.{child.name}", child)
            else:
                self._visit(child, scope, fn)

    def resolve(self, node: ast.AST | None) -> ast.AST | None:
        """A literal, or what a name of this module or one imported from a package module is bound to."""
        node = _literal(node)
        if isinstance(node, ast.Name):
            if node.id in self.literals:
                return self.literals[node.id]
            module, attr = self.imported.get(node.id, ("", ""))
            if attr and module in self.others:
                return self.others[module].literals.get(attr, node)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            module, attr = self.imported.get(node.value.id, ("", ""))
            if module in self.others and not attr:
                return self.others[module].literals.get(node.attr, node)
        return node

    def words(self, node: ast.AST | None) -> list[str]:
        """The strings a compared operand holds: a string, a collection's elements, a dict's keys."""
        node = self.resolve(node)
        if _is_str(node):
            return [node.value]
        elts = node.keys if isinstance(node, ast.Dict) else node.elts if isinstance(node, COLLECTIONS) else []
        return [e.value for e in elts if _is_str(e)]


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), str(path))


def walk(mods: dict[str, Path], root: Path, names: Registered,
         parse: Callable[[Path], ast.Module] = _parse) -> list[Hit]:
    """Every comparison with, and pick of, a registered name outside the registry, the stand-ins and the name's
    home, sorted by file and line. ``mods``: module name -> file; ``root``: the folder holding the package."""
    every = {name: _Module(parse(path), set(mods)) for name, path in mods.items()}
    wrappers = {fn: at for m in every.values() for fn, at in m.wrappers.items()}
    hits: set[Hit] = set()
    for mod_name, m in every.items():
        rel = mods[mod_name].relative_to(root).as_posix()
        if mod_name == registry.__name__ or any(rel.startswith(s + "/") for s in STANDINS):
            continue
        m.others = every
        # (scope, subject) -> [(line, words, code)]: what one expression is compared with in one function
        compared: dict[tuple[str, str], list[tuple[int, list[str], ast.AST]]] = {}
        picked: list[tuple[int, str, ast.AST]] = []

        def compare(scope: str, subject: ast.AST, words: list[str], at: ast.AST) -> None:
            if words:
                compared.setdefault((scope, ast.unparse(subject)), []).append((at.lineno, words, at))

        def pick(value: ast.AST | None, at: ast.AST) -> None:
            if _is_str(value) and value.value in names.homes:
                picked.append((at.lineno, value.value, at))

        for scope, node in m.nodes:
            if isinstance(node, ast.Compare):
                left = node.left
                for op, right in zip(node.ops, node.comparators):
                    if isinstance(op, (ast.Eq, ast.NotEq, ast.Is, ast.IsNot)):
                        if _is_str(m.resolve(right)):
                            compare(scope, left, m.words(right), node)
                        elif _is_str(m.resolve(left)):
                            compare(scope, right, m.words(left), node)
                    elif isinstance(op, (ast.In, ast.NotIn)) and isinstance(m.resolve(right), COLLECTIONS):
                        compare(scope, left, m.words(right), node)
                    left = right
            elif isinstance(node, ast.Match):
                compare(scope, node.subject, [p.value.value for case in node.cases for p in ast.walk(case.pattern)
                                              if isinstance(p, ast.MatchValue) and _is_str(p.value)], node.subject)
            elif isinstance(node, ast.Subscript) and not _is_str(node.slice):
                table = m.resolve(node.value)
                if isinstance(table, ast.Dict):
                    compare(scope, node.slice, m.words(table), node)
                    for value in table.values:
                        pick(value, node)
            elif isinstance(node, ast.Call):
                attr, owner = _callee(node), node.func.value if isinstance(node.func, ast.Attribute) else None
                if owner is not None and attr in ("startswith", "endswith") and node.args:
                    compare(scope, owner, m.words(node.args[0]), node)
                table = m.resolve(owner)
                if attr == "get" and isinstance(table, ast.Dict) and node.args and not _is_str(node.args[0]):
                    compare(scope, node.args[0], m.words(table), node)
                    for value in table.values:
                        pick(value, node)
                if _picks_kind(node):
                    pick(node.args[1], node)
                elif attr in wrappers and len(node.args) > wrappers[attr]:
                    pick(node.args[wrappers[attr]], node)
                for keyword in node.keywords:
                    if keyword.arg == "default":
                        pick(keyword.value, node)
                    elif keyword.arg == "choices":  # argparse: a membership test
                        compare(scope, node.args[0] if node.args else node, m.words(keyword.value), node)
            elif isinstance(node, ast.IfExp):
                pick(node.body, node)
                pick(node.orelse, node)
            elif isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or):
                pick(node.values[-1], node)

        for group in compared.values():
            if any(names.name_of(w) is None for _, words, _ in group for w in words):
                continue  # another vocabulary that shares a word with a kind (see the module's docstring)
            for line, words, at in group:
                for name in map(names.name_of, words):
                    if not names.at_home(name, rel):
                        hits.add(Hit(f"{rel}:{line}", name, ast.unparse(at)[:100]))
        for line, name, at in picked:
            if not names.at_home(name, rel):
                hits.add(Hit(f"{rel}:{line}", name, ast.unparse(at)[:100]))
    return sorted(hits, key=lambda h: (h.where.rpartition(":")[0], int(h.where.rpartition(":")[2]), h.name))
