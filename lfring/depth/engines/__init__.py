"""Depth engines, one module each, registered here in :data:`ENGINES` (the ``method`` of
:func:`lfring.estimate_depth`).

A new engine is a module that defines a :class:`lfring.depth.engines.base.DepthEngine` and one
line below that registers it.
"""

from lfring.core.registry import Registry
from lfring.depth.engines.base import DepthEngine
from lfring.depth.engines.local import LOCAL
from lfring.depth.engines.semiglobal import SEMIGLOBAL, SEMIGLOBAL_REFERENCE

__all__ = ["ENGINES", "DepthEngine"]

ENGINES = Registry("method")
for _engine in (SEMIGLOBAL, LOCAL, SEMIGLOBAL_REFERENCE):
    ENGINES.register(_engine.name, _engine)
