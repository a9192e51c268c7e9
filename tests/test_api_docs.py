"""The public API is documented: every public function, class and method in lfring/ has a
docstring, and the entry points of the pipeline carry an Examples section on the bundled
frames (data/synthetic) that pytest runs as a doctest (--doctest-modules over lfring/)."""

import ast
import doctest
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "lfring"

# The pipeline's entry points: each shows itself on the bundled frames.
WITH_EXAMPLES = (
    "lfring.load_raw",
    "lfring.demosaic",
    "lfring.detect_layout",
    "lfring.split_views",
    "lfring.calibrate",
    "lfring.RingCalibration",
    "lfring.refocus",
    "lfring.focal_stack",
    "lfring.all_in_focus",
    "lfring.estimate_depth",
    "lfring.inspect_frame",
    "lfring.batch.run_batch",
)


def _public_modules():
    """Every module of the package but the private ones (a part of the path starting with '_',
    other than __init__ and __main__)."""
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if any(p.startswith("_") and p not in ("__init__", "__main__") for p in parts):
            continue
        yield path


def _undocumented(path):
    """Qualified names of the public functions, classes and methods of a module (at module and
    class level, public classes only) that lack a docstring."""
    missing = []

    def walk(body, prefix):
        for node in body:
            if isinstance(node, (ast.If, ast.Try)):  # definitions under `if` / `try` at this level
                walk(node.body + node.orelse + getattr(node, "finalbody", []), prefix)
                for handler in getattr(node, "handlers", []):
                    walk(handler.body, prefix)
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
                if ast.get_docstring(node) is None:
                    missing.append(f"{prefix}{node.name} (line {node.lineno})")
                if isinstance(node, ast.ClassDef):
                    walk(node.body, f"{prefix}{node.name}.")

    walk(ast.parse(path.read_text(encoding="utf-8")).body, "")
    return missing


def test_the_walk_finds_the_package_and_catches_a_missing_docstring(tmp_path):
    modules = list(_public_modules())
    assert len(modules) > 50 and PACKAGE / "io" / "raw.py" in modules
    assert PACKAGE / "_resources.py" not in modules
    bad = tmp_path / "bad.py"
    bad.write_text(
        'def documented():\n    """Yes."""\n\n\ndef bare():\n    pass\n\n\ndef _private():\n    pass\n\n\n'
        'class Thing:\n    """A thing."""\n\n    def method(self):\n        return 1\n\n'
        '    @property\n    def size(self):\n        """Its size."""\n        return 2\n'
    )
    assert _undocumented(bad) == ["bare (line 5)", "Thing.method (line 16)"]


def test_every_public_function_class_and_method_has_a_docstring():
    missing = [f"{path.relative_to(ROOT)}: {name}" for path in _public_modules() for name in _undocumented(path)]
    assert not missing, "public API without a docstring:\n" + "\n".join(missing)


def _resolve(dotted):
    import importlib

    module, _, name = dotted.rpartition(".")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("dotted", WITH_EXAMPLES)
def test_entry_points_have_an_examples_section_on_the_bundled_frames(dotted):
    obj = _resolve(dotted)
    doc = obj.__doc__ or ""
    assert re.search(r"^\s*Examples\n\s*--------\n", doc, re.M), f"{dotted}: no numpydoc Examples section"
    examples = doctest.DocTestParser().get_examples(doc.split("Examples", 1)[1])
    assert examples, f"{dotted}: its Examples section has no doctest"
    assert any("data/synthetic/" in ex.source for ex in examples), f"{dotted}: its example does not use the bundled frames"
    # The examples show results (an expected output) rather than only running code.
    assert any(ex.want.strip() for ex in examples), f"{dotted}: its example shows no result"
    # pytest collects it: the docstring is the object's own, in a module under lfring/.
    found = doctest.DocTestFinder().find(obj, dotted.rsplit(".", 1)[1])
    assert found and found[0].examples
    assert Path(found[0].filename).resolve().is_relative_to(PACKAGE)


def test_the_warnings_docstrings_name_are_at_the_top_level():
    """refocus's docstring names lfring.LfringWarning: a filter written from it must work."""
    import warnings

    import lfring

    assert issubclass(lfring.OverExposureWarning, lfring.LfringWarning)
    with warnings.catch_warnings():
        warnings.simplefilter("error", lfring.LfringWarning)
        with pytest.raises(lfring.LfringWarning):
            warnings.warn("x", lfring.OverExposureWarning)
