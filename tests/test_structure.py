"""The package's structure: no import cycles, no private names imported across modules, one
definition of each shared warping rule, and no function hiding a module of the same name."""

import ast
import importlib
import pkgutil
from collections import defaultdict
from pathlib import Path

import lfring

ROOT = Path(lfring.__file__).parent


def _modules() -> dict[str, Path]:
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _imports(mods):
    """Edges (importer -> imported lfring module, at any depth of the code: imports inside
    functions count) and private names imported from another module."""
    edges, private = defaultdict(set), []
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".")[: len(name.split(".")) - node.level + (1 if is_pkg else 0)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("lfring"):
                    continue
                for alias in node.names:
                    full = f"{target}.{alias.name}"
                    dst = full if full in mods else target
                    if dst in mods and dst != name and not name.startswith(dst + "."):
                        edges[name].add(dst)
                    if alias.name.startswith("_") and not alias.name.startswith("__") and full not in mods and dst != name:
                        private.append(f"{name} imports {full}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in mods and alias.name != name and not name.startswith(alias.name + "."):
                        edges[name].add(alias.name)
    return edges, private


def _cycles(edges) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_and_no_private_imports():
    mods = _modules()
    assert "lfring.core.warping" in mods and "lfring.depth.sweep" in mods
    edges, private = _imports(mods)
    assert edges["lfring.focus"] >= {"lfring.core.warping"}  # the walk sees imports
    assert _cycles(edges) == []
    assert private == []


def test_the_detector_finds_a_cycle_and_a_private_import(tmp_path):
    """The checks above can fail: a planted cycle and reach-in are found."""
    pkg = tmp_path / "lfring"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from lfring.b import _g\n")
    (pkg / "b.py").write_text("from lfring.a import f\n\ndef _g():\n    pass\n")
    mods = {"lfring": pkg / "__init__.py", "lfring.a": pkg / "a.py", "lfring.b": pkg / "b.py"}
    edges, private = _imports(mods)
    assert _cycles(edges) == [["lfring.a", "lfring.b"]]
    assert private == ["lfring.a imports lfring.b._g"]


def _definitions():
    """(module, name) of every function and class defined anywhere in lfring."""
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                yield name, node.name


def test_one_definition_of_each_warping_rule():
    """The translation test, the shift engine, the view-mask cache and the view-stack check are
    written once, in lfring.core."""
    defs = list(_definitions())
    where = lambda pred: sorted({m for m, n in defs if pred(n.strip("_").lower())})
    assert where(lambda n: n in ("translation_of", "translations", "is_translation")) == ["lfring.core.warping"]
    assert where(lambda n: n.endswith(("shifter", "shiftplan", "shiftengine"))) == ["lfring.core.shift"]
    assert where(lambda n: n == "check_views") == ["lfring.core.viewstack"]
    caches = sorted({name for name, path in _modules().items() if "WeakKeyDictionary" in path.read_text(encoding="utf-8")})
    assert caches == ["lfring.core.viewstack"]


def test_no_function_hides_a_module():
    """``import lfring.x.y as m`` gives the module: no package exports a name that is also one of
    its submodules (which forced tests to reach into sys.modules)."""
    clashes = []
    for name in _modules():
        pkg = importlib.import_module(name)
        if not hasattr(pkg, "__path__"):
            continue
        for info in pkgutil.iter_modules(pkg.__path__):
            attr = getattr(pkg, info.name, None)
            if attr is not None and not hasattr(attr, "__path__") and getattr(attr, "__name__", None) != f"{name}.{info.name}":
                clashes.append(f"{name}.{info.name}")
    assert clashes == []
