"""The package's import graph: no cycle between modules, and every import points down the layers; and no
kind string compared outside its registry (the walk: ``tests/_kind_names.py``).

Every module is parsed (ast), so imports inside functions (the lazy ones) count too. A module
may import its own layer and the layers below it; ``nao_trainer.x.y`` belongs to the layer of
``x`` (a folder or a top-level module).
"""
from __future__ import annotations

import ast
import sys
from functools import lru_cache
from pathlib import Path

import nao_trainer
from _kind_names import STANDINS, Registered, walk

PACKAGE = Path(nao_trainer.__file__).parent

#: Low to high. A module may import from its own layer and from the layers before it.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("__init__", "errors", "files", "ports", "registry"),
    ("core",),
    ("tasks",),
    ("data",),
    ("robot", "eeg", "answers", "console"),
    ("learn",),
    ("policies",),
    ("experiments",),
    ("session",),
    ("study",),
    ("plots",),
    ("cli", "__main__"),
)
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def _local_imports():
    """tools/local_imports.py, loaded afresh (a test monkeypatches its package): its module walk is this file's too."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("local_imports", PACKAGE.parent / "tools" / "local_imports.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["local_imports"] = module  # its dataclass looks its module up
    spec.loader.exec_module(module)
    return module


WALK = _local_imports()


def modules() -> dict[str, Path]:
    return dict(WALK.modules())


@lru_cache(maxsize=None)
def parsed(path: Path) -> ast.Module:
    """A module's tree, parsed once per test process (the import graph and the kind-name walk read it)."""
    return ast.parse(path.read_text(encoding="utf-8"), str(path))


def imports_of(name: str, path: Path) -> set[str]:
    """The package modules ``name`` imports (``from a import b`` counts ``a.b`` when it is a module)."""
    return {target for node in ast.walk(parsed(path)) if isinstance(node, (ast.Import, ast.ImportFrom))
            for target in WALK.targets(name, path, node) if target.startswith("nao_trainer") and target != name}


def graph() -> dict[str, set[str]]:
    return {name: imports_of(name, path) for name, path in modules().items()}


def layer_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_module_has_a_layer():
    missing = sorted({layer_of(m) for m in modules()} - set(RANK))
    assert not missing, f"add these to LAYERS in tests/test_layers.py: {missing}"


def test_imports_point_down():
    upward = sorted(f"{src} -> {dst} ({layer_of(src)} imports {layer_of(dst)})"
                    for src, targets in graph().items() for dst in targets
                    if RANK[layer_of(dst)] > RANK[layer_of(src)])
    assert not upward, "imports from a lower layer to a higher one:\n" + "\n".join(upward)


def find_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return sorted(cycles)


def test_find_cycles_finds_a_circle_and_nothing_else():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    edges = graph()
    # a package's __init__ re-exporting its own modules is not a circle through them
    edges = {src: {dst for dst in targets if not (src.startswith(dst + ".") and modules_is_package(dst))}
             for src, targets in edges.items()}
    cycles = find_cycles(edges)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def modules_is_package(name: str) -> bool:
    return (PACKAGE.parent / Path(*name.split(".")) / "__init__.py").exists()


def test_every_function_local_import_of_the_package_has_its_reason():
    """Issue 26: a function-local import of a package module is a cycle broken, a heavy package kept out of a
    module that loads none (``tools/local_imports.py`` works it out from the code), or an optional extra;
    anything else belongs at the top of its module."""
    tool = _local_imports()
    sites = tool.sites()
    assert sites, "no function-local import found: the walk is broken"
    bare = [f"{s.path} imports {s.target}" for s in sites if not s.reason]
    assert not bare, "function-local imports with no reason (move them to the top of the module):\n" + "\n".join(bare)


def test_a_free_local_import_is_found_and_a_heavy_one_is_not(tmp_path, monkeypatch):
    """The walk itself: in a copy of two modules, a local import of a module that loads nothing heavy has no
    reason, one that loads numpy into a module without it does, and a guarded one names the extra."""
    tool = _local_imports()
    pkg = tmp_path / "nao_trainer"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "light.py").write_text("import json\n")
    (pkg / "heavy.py").write_text("import numpy as np\n")
    (pkg / "user.py").write_text("def f():\n    from nao_trainer import light\n\n"
                                 "def g():\n    from nao_trainer.heavy import np\n\n"
                                 "def h():\n    try:\n        from nao_trainer import light\n"
                                 "    except ImportError:\n        raise SystemExit(2)\n")
    monkeypatch.setattr(tool, "PACKAGE", pkg)
    for cached in (tool.modules, tool._parsed, tool.closure):
        cached.cache_clear()
    found = {s.path: s.reason for s in tool.sites()}
    assert found == {"nao_trainer/user.py:2": "", "nao_trainer/user.py:5": "loads numpy",
                     "nao_trainer/user.py:9": "extra: an optional extra, refused in one line when missing"}


def test_no_kind_string_is_compared_outside_its_registry():
    """Issue 26's build rule: outside ``registry.py`` and a plug-in's home, no code compares or picks a
    registered kind's name; it asks the plug-in."""
    names = Registered.read(modules(), PACKAGE.parent)
    assert {"sequence", "nback", "usp", "bayes", "muse", "nao"} <= set(names.homes), names.homes
    assert names.homes["nao"] == ("nao_trainer/robot/models",), names.homes["nao"]
    for folder, reason in STANDINS.items():
        print(f"outside the rule: {folder}/ ({reason})")
    hits = walk(modules(), PACKAGE.parent, names, parsed)
    assert not hits, (f"{len(hits)} kind names compared or picked outside the registry and the plug-in's home "
                      "(ask the plug-in: an attribute it declares, registry.spec/load, the setting's declared "
                      "default):\n" + "\n".join(map(str, hits))
                      + "\nOutside the rule: " + "; ".join(f"{f}/: {r}" for f, r in STANDINS.items()))


def test_the_walk_finds_a_planted_comparison_and_passes_the_legal_ones(tmp_path):
    """The walk itself, on a package of its own: each planted comparison or pick of a registered name is found
    with its line; the same words at home, in another vocabulary, as a column name, in a stand-in or in the
    setting's declaration are not."""
    pkg = tmp_path / "nao_trainer"
    for folder in ("robot/models", "robot/standin", "session", "tasks/sequence"):
        (pkg / folder).mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "robot" / "models" / "nao.py").write_text('def f(model):\n    return model == "pepper"\n')
    (pkg / "robot" / "standin" / "body.py").write_text('BODIES = {"nao": 1, "pepper": 2}\n'
                                                       'def f(m):\n    return BODIES[m]\n')
    (pkg / "tables.py").write_text('MODELS = ("nao", "pepper")\nDEFAULT = "nao"\n')
    (pkg / "devices.py").write_text("from nao_trainer import registry\n\n"
                                    "def make_device(name, data=None):\n"
                                    "    return registry.make('eeg_device', name, data)\n")
    wiring = (
        "from nao_trainer.tables import MODELS\n"
        "from nao_trainer import tables\n"
        "from nao_trainer.devices import make_device\n"
        "from nao_trainer.settings import setting\n\n"
        "def legal(config, mode, row, kind):\n"
        "    a = mode in ('disabled', 'random', 'contextual')\n"  # NAOqi's speaking modes
        "    b = kind == 'random' or kind == 'oracle'\n"  # the evaluation's strategies
        "    c = row['sequence'] if 'sequence' in row else None\n"  # a column
        "    d = setting('muse', kind=str)\n"  # the declared default
        "    return a, b, c, d\n\n"
        "def planted(config, task, spec, parser):\n"
        "    if config.robot.model == 'pepper':  # pepper\n"
        "        pass\n"
        "    x = config.robot.model in MODELS  # nao pepper\n"
        "    y = task.name != 'sequence'  # sequence\n"
        "    z = spec.startswith('usp:')  # usp\n"
        "    match config.eeg.device:  # muse brainflow\n"
        "        case 'muse' | 'brainflow':\n"
        "            pass\n"
        "    w = make_device('muse')  # muse\n"
        "    v = config.task.name or 'sequence'  # sequence\n"
        "    u = {'nao': 1, 'pepper': 2}[config.robot.model]  # nao pepper\n"
        "    t = config.robot.model == tables.DEFAULT  # nao\n"
        "    parser.add_argument('--model', choices=('nao', 'pepper'))  # nao pepper\n"
        "    parser.add_argument('button', choices=('A', 'B', 'C'))\n"
        "    return x, y, z, w, v, u, t\n")
    (pkg / "session" / "wiring.py").write_text(wiring)
    (pkg / "tasks" / "sequence" / "__init__.py").write_text("def f(task):\n    return task == 'sequence'\n")
    mods = {name: path for name, path in ((".".join(p.relative_to(tmp_path).with_suffix("").parts)
                                           .removesuffix(".__init__"), p) for p in sorted(pkg.rglob("*.py")))}
    names = Registered({"nao": ("nao_trainer/robot/models",), "pepper": ("nao_trainer/robot/models",),
                        "sequence": ("nao_trainer/tasks/sequence",), "usp": ("nao_trainer/policies",),
                        "random": ("nao_trainer/policies",), "muse": ("nao_trainer/eeg/devices",),
                        "brainflow": ("nao_trainer/eeg/devices",)})
    found = {(h.where, h.name) for h in walk(mods, tmp_path, names)}
    planted = {(f"nao_trainer/session/wiring.py:{n}", name) for n, line in enumerate(wiring.splitlines(), 1)
               if "  # " in line for name in line.partition("  # ")[2].split()}
    assert len(planted) == 14
    assert found == planted, found ^ planted
