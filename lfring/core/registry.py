"""Named strategies of a stage (depth costs, depth engines, refocusing methods), one table each.

A stage with several strategies keeps each in a module of its own and registers it in the
stage's :class:`Registry`; the stage's entry point looks the name up instead of branching on it,
so a new strategy is one new module and one registration.
"""

from __future__ import annotations

from collections.abc import Mapping

from lfring.core.validate import check_choice
from lfring.errors import InvalidInputError

__all__ = ["Registry"]


class Registry(Mapping):
    """An ordered table of named strategies (a read-only mapping once filled).

    Parameters
    ----------
    parameter : str
        The name of the argument that selects a strategy (``cost``, ``method``...): errors say it.

    Examples
    --------
    >>> methods = Registry("method")
    >>> methods.register("fast", len)
    <built-in function len>
    >>> methods.lookup("fast") is len, list(methods)
    (True, ['fast'])
    >>> methods.lookup("slow")
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: method must be one of fast, got 'slow'
    """

    def __init__(self, parameter: str):
        self.parameter = parameter
        self._entries: dict = {}

    def register(self, name: str, entry):
        """Add ``entry`` under ``name`` (once) and return it, so it can decorate a definition."""
        if not isinstance(name, str) or not name:
            raise InvalidInputError(f"a {self.parameter} is registered under a non-empty name, got {name!r}")
        if name in self._entries:
            raise InvalidInputError(f"{self.parameter} {name!r} is registered already")
        self._entries[name] = entry
        return entry

    def lookup(self, name):
        """The entry of ``name``, or an error that lists the registered names."""
        return self._entries[check_choice(name, self.parameter, self._entries)]

    def __getitem__(self, name):
        return self._entries[name]

    def __iter__(self):
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.parameter!r}: {', '.join(self._entries)})"
