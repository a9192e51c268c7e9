"""The table of a stage's named strategies, and the three tables the stages fill."""

import pytest

from lfring.core.registry import Registry
from lfring.errors import InvalidInputError


def test_lookup_register_and_errors():
    table = Registry("cost")
    assert table.register("a", 1) == 1 and table.register("b", 2) == 2
    assert table.lookup("b") == 2 and list(table) == ["a", "b"] and len(table) == 2 and "a" in table
    with pytest.raises(InvalidInputError, match="cost must be one of a, b, got 'c'"):
        table.lookup("c")
    with pytest.raises(InvalidInputError, match="registered already"):
        table.register("a", 3)
    with pytest.raises(InvalidInputError, match="non-empty name"):
        table.register("", 3)


def test_every_registered_strategy_carries_its_own_name():
    from lfring.depth.costs import COSTS
    from lfring.depth.engines import ENGINES
    from lfring.focus.methods import METHODS

    for table in (COSTS, ENGINES, METHODS):
        assert all(entry.name == name for name, entry in table.items())
    assert all(ENGINES[e].default_cost in COSTS for e in ENGINES)
    assert [m for m in METHODS if "torch" in METHODS[m].backends] == ["shift-and-add"]
