"""The package's structure: no import cycles between modules or between the packages of any level,
no import that reaches up the pipeline, no private names imported across modules, one definition
of each shared rule and one argument-check module, and no function hiding a module of the same
name. Each check is also shown to fail on a planted package."""

import ast
import importlib
import pkgutil
from collections import defaultdict
from pathlib import Path

import lfring

ROOT = Path(lfring.__file__).parent

# The pipeline from the bottom up: a package may import those before it, never one after it (a
# stage never reaches up to dispatch; what several stages share lives below them, in lfring.core).
PIPELINE = (
    "lfring.errors", "lfring._resources", "lfring.core", "lfring.io", "lfring.views", "lfring.optics",
    "lfring.calibration", "lfring.synth", "lfring.depth", "lfring.check", "lfring.focus", "lfring.inspect",
    "lfring.viewer", "lfring.batch", "lfring", "lfring.cli", "lfring.__main__",
)
# The one module that decides what an integer, a number or a choice is.
VALIDATION = "lfring.core.validate"


def _modules(root: Path = ROOT) -> dict[str, Path]:
    out = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
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
    """Strongly connected components of more than one node (Tarjan)."""
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


def _package_cycles(mods, edges) -> list[list[str]]:
    """Cycles between the children of any package: lfring.a.x -> lfring.b.y is an edge between
    lfring.a and lfring.b, lfring.depth.costs.lcn -> lfring.depth.sweep.strips one between
    lfring.depth.costs and lfring.depth.sweep, even when no two modules form a loop."""
    packages = {m for m, p in mods.items() if p.name == "__init__.py"}
    out = []
    for pkg in sorted(packages):
        depth = len(pkg.split(".")) + 1

        def child(m):
            parts = m.split(".")
            return ".".join(parts[:depth]) if m.startswith(pkg + ".") and len(parts) >= depth else None

        group = defaultdict(set)
        for a, bs in edges.items():
            for b in bs:
                ca, cb = child(a), child(b)
                if ca and cb and ca != cb:
                    group[ca].add(cb)
        out += _cycles(group)
    return out


def _layer(name: str) -> int | None:
    """The place of a module's top-level package in PIPELINE."""
    parts = name.split(".")
    for k in (2, 1):
        key = ".".join(parts[:k])
        if key in PIPELINE and (k == 1 and len(parts) == 1 or k == 2):
            return PIPELINE.index(key)
    return None


def _upward(edges) -> list[str]:
    """Imports that reach a package later in PIPELINE than the importer's."""
    out = []
    for a, bs in edges.items():
        for b in bs:
            la, lb = _layer(a), _layer(b)
            if la is None or lb is None or lb > la:
                out.append(f"{a} -> {b}")
    return sorted(out)


def _hand_checks(mods) -> list[str]:
    """Modules other than VALIDATION that check a scalar argument by hand: ``isinstance(x, bool)``
    (or a tuple with bool, numbers.Real/Integral, np.integer/np.floating), the pattern of a
    number or count check; and calibrations recognised by ``hasattr`` instead of the protocol."""
    def names(node):
        elts = node.elts if isinstance(node, ast.Tuple) else [node]
        for e in elts:
            yield ast.unparse(e)

    out = []
    for name, path in mods.items():
        if name == VALIDATION:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Name) or len(node.args) != 2:
                continue
            if node.func.id == "isinstance":
                kinds = set(names(node.args[1]))
                if kinds & {"bool", "np.bool_", "numbers.Real", "numbers.Integral", "np.integer", "np.floating"}:
                    out.append(f"{name}:{node.lineno}: isinstance(..., {ast.unparse(node.args[1])})")
            elif node.func.id == "hasattr" and isinstance(node.args[1], ast.Constant) and node.args[1].value in (
                    "homographies", "check_fits", "layout"):
                out.append(f"{name}:{node.lineno}: hasattr(..., {node.args[1].value!r})")
    return sorted(out)


def test_no_import_cycles_and_no_private_imports():
    mods = _modules()
    assert "lfring.core.warping" in mods and "lfring.depth.estimate" in mods
    edges, private = _imports(mods)
    assert edges["lfring.focus.render"] >= {"lfring.core.warping"}  # the walk sees imports
    assert _cycles(edges) == []
    assert private == []


def test_no_cycle_between_the_packages_of_any_level():
    mods = _modules()
    edges, _ = _imports(mods)
    assert "lfring.depth.costs" in mods and "lfring.depth.engines" in mods
    assert _package_cycles(mods, edges) == []


def test_no_import_reaches_up_the_pipeline():
    """Every package of lfring has its place in PIPELINE, and imports only those below it."""
    mods = _modules()
    unplaced = sorted(m for m in mods if _layer(m) is None)
    assert unplaced == []
    edges, _ = _imports(mods)
    assert _upward(edges) == []


def test_one_argument_check_module():
    """Scalars are checked by lfring.core.validate alone; calibrations by the protocol."""
    assert _hand_checks(_modules()) == []


def _plant(tmp_path, files: dict[str, str]) -> dict[str, Path]:
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return _modules(tmp_path / "lfring")


def test_the_checks_can_fail(tmp_path):
    """A planted package with a module cycle, a private reach-in, a loop between two subpackages
    that no two modules close, an upward dispatch import and a second argument check: each
    check finds its defect."""
    mods = _plant(tmp_path, {
        "lfring/__init__.py": "",
        "lfring/a.py": "def f():\n    from lfring.b import _g\n",
        "lfring/b.py": "from lfring.a import f\n\ndef _g():\n    pass\n",
        "lfring/depth/__init__.py": "",
        "lfring/depth/sweep.py": "def run(x):\n    from lfring.focus.torch import twin\n    return twin(x)\n",
        "lfring/depth/base.py": "",
        "lfring/focus/__init__.py": "",
        "lfring/focus/torch.py": "from lfring.depth.base import *\n\ndef twin(x):\n    return x\n",
        "lfring/core/__init__.py": "",
        "lfring/core/check.py": "def ok(n):\n    if isinstance(n, bool) or n < 1:\n        raise ValueError(n)\n",
        "lfring/core/cal.py": "def is_cal(c):\n    return hasattr(c, 'homographies')\n",
    })
    edges, private = _imports(mods)
    assert _cycles(edges) == [["lfring.a", "lfring.b"]]
    assert private == ["lfring.a imports lfring.b._g"]
    assert ["lfring.depth", "lfring.focus"] in _package_cycles(mods, edges)
    assert "lfring.depth.sweep -> lfring.focus.torch" in _upward(edges)
    assert _hand_checks(mods) == ["lfring.core.cal:2: hasattr(..., 'homographies')",
                                  "lfring.core.check:2: isinstance(..., bool)"]


def _definitions():
    """(module, name) of every function and class defined anywhere in lfring."""
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                yield name, node.name


def test_one_definition_of_each_shared_rule():
    """The translation test, the shift engine, the view-mask cache, the view-stack check and each
    argument check are written once, in lfring.core."""
    defs = list(_definitions())
    where = lambda pred: sorted({m for m, n in defs if pred(n.strip("_").lower())})
    assert where(lambda n: n in ("translation_of", "translations", "is_translation")) == ["lfring.core.warping"]
    assert where(lambda n: n.endswith(("shifter", "shiftplan", "shiftengine"))) == ["lfring.core.shift"]
    assert where(lambda n: n == "check_views") == ["lfring.core.viewstack"]
    for check in ("check_int", "check_number", "check_fraction", "check_choice", "check_odd_px", "check_threads"):
        assert where(lambda n, c=check: n == c) == [VALIDATION], check
    caches = sorted({name for name, path in _modules().items() if "WeakKeyDictionary" in path.read_text(encoding="utf-8")})
    assert caches == ["lfring.core.viewstack"]


def test_strategies_are_looked_up_not_branched_on():
    """Depth costs, depth engines and refocusing methods each have one registry, and no module
    compares a cost or method name to a string literal to dispatch."""
    from lfring.depth.costs import COSTS
    from lfring.depth.engines import ENGINES
    from lfring.focus.methods import METHODS

    assert {"lcn", "lcn-halves", "zncc"} <= set(COSTS) and {"sgm", "local"} <= set(ENGINES)
    assert set(METHODS) >= {"shift-and-add", "depth-aware"}
    branches = []
    for name, path in _modules().items():
        if name.startswith("lfring.cli"):
            continue  # option handling, not dispatch
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Compare) and isinstance(node.left, ast.Name) and node.left.id in ("cost", "method"):
                strings = [c for c in node.comparators if isinstance(c, ast.Constant) and isinstance(c.value, str)]
                tuples = [c for c in node.comparators if isinstance(c, ast.Tuple)]
                if strings or tuples:
                    branches.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    assert branches == []


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
