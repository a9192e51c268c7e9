"""What the fused semi-global passes share (:mod:`lfring.depth.engines.fused_volume`,
:mod:`lfring.depth.engines.fused_paths`): the integer cost representation and the numba
settings of their kernels.

A cost is held in uint16 units of a fraction of the path penalty: a path's value exceeds its cost
by at most the large-jump penalty, so when the cost is clipped to :data:`COST_MAX` and the
penalties stay below :data:`PENALTY_MAX`, a path and a step's sums fit in int16 (the paths'
state) and a sum of four paths in uint16.
"""

from __future__ import annotations

from lfring.core.compiled import COMPILED

__all__ = ["COST_MAX", "COST_ZERO", "FAST", "INLINE", "JIT", "PARALLEL", "PENALTY_MAX", "UNKNOWN"]

# Fast maths without "no infinities": unknown costs are inf until they are quantised.
FAST = {"nsz", "arcp", "contract", "afn"}
JIT = dict(COMPILED, fastmath=FAST)
PARALLEL = dict(JIT, parallel=True)
# Small row helpers are inlined into their callers: a call per row and hypothesis costs more than
# the row itself on the short rows of a span or a block of columns.
INLINE = dict(JIT, inline="always")
# Box sums and minima of the default 5-pixel window run in one pass over five rows (or shifted
# columns) from rows this wide; on the halves pass's short rows the one-pass loop was no faster
# than a pass per row (see benchmarks/RESULTS.md).
ONE_PASS_MIN_WIDTH = 128
# A cost that no two views saw: never a winner; the paths see the pixel's mean known cost there.
UNKNOWN = 65535
# The largest cost and penalty kept: 4 * (COST_MAX + PENALTY_MAX) < 2**16 (the four paths' sum),
# 2 * (COST_MAX + PENALTY_MAX) < 2**15 (two paths, as the horizontal pass adds them in int16).
COST_MAX = 12000
PENALTY_MAX = 4000
# The integer that stands for a cost of 0: where the views agree, float rounding makes the cost
# slightly negative, and those values keep their place below the others. The paths' sums carry
# it once per path, the box means once; the distinctness measures take it off.
COST_ZERO = 1024
