"""Refocusing: at any metric depth, focal stacks and all-in-focus images.

- :mod:`lfring.focus.render`: the entry points :func:`refocus`, :func:`focal_stack`,
  :func:`all_in_focus`;
- :mod:`lfring.focus.methods`: the table of refocusing methods, one module each:
  :mod:`lfring.focus.shift_and_add` (with :class:`Refocuser`, the fast path for many frames at
  one depth, and its torch twin) and :mod:`lfring.focus.depth_aware` (the depth-aware renderer).
"""

from lfring.focus.depth_aware import DepthOfField, depth_of_field, resolve_aperture
from lfring.focus.methods import METHODS
from lfring.focus.render import all_in_focus, focal_stack, refocus
from lfring.focus.shift_and_add import Refocuser

__all__ = ["METHODS", "DepthOfField", "Refocuser", "all_in_focus", "depth_of_field", "focal_stack", "refocus",
           "resolve_aperture"]
