"""Refocusing methods, one module each (:mod:`lfring.focus.shift_and_add`,
:mod:`lfring.focus.depth_aware`), registered here in :data:`METHODS`.

A new method is a module that defines a :class:`lfring.focus.base.RefocusMethod` and one line
below that registers it; :func:`lfring.refocus` looks methods up by name.
"""

from lfring.core.registry import Registry
from lfring.focus.depth_aware import DEPTH_AWARE
from lfring.focus.shift_and_add import SHIFT_AND_ADD

__all__ = ["METHODS"]

METHODS = Registry("method")
for _method in (SHIFT_AND_ADD, DEPTH_AWARE):
    METHODS.register(_method.name, _method)
