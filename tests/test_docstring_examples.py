"""The examples in the public API's docstrings run as pasted after ``import lfring``: every name
they use is one they import or define, never one of the module they sit in."""

import ast
import builtins
import doctest
import importlib

import pytest

# The public API's modules whose examples a user pastes (views.py and calibration/ follow when
# their restructuring lands).
MODULES = ("lfring.io.raw", "lfring.io.demosaic", "lfring.io.bayer", "lfring.io.writers", "lfring.focus.render",
           "lfring.focus.shift_and_add", "lfring.inspect.measure", "lfring.batch.run", "lfring.batch.record",
           "lfring.optics.device", "lfring.optics.positions", "lfring.optics.raytrace", "lfring.depth.io",
           "lfring.depth.selection", "lfring.check")


def _unbound(test: doctest.DocTest) -> set[str]:
    defined = set(dir(builtins))
    missing = set()
    for ex in test.examples:
        tree = ast.parse(ex.source)
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                defined.update((a.asname or a.name).split(".")[0] for a in node.names)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
                defined.add(node.id)
            elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                defined.add(node.name)
            elif isinstance(node, ast.arg):
                defined.add(node.arg)
        missing |= {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)} - defined
    return missing


@pytest.mark.parametrize("module", MODULES)
def test_examples_use_only_names_they_import(module):
    mod = importlib.import_module(module)
    tests = [t for t in doctest.DocTestFinder(exclude_empty=True).find(mod) if t.examples]
    unbound = {t.name: sorted(_unbound(t)) for t in tests if _unbound(t)}
    assert unbound == {}
