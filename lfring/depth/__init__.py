"""Depth from the views: plane sweep with confidence, metrics and outputs.

The entry point is :func:`estimate_depth` (:mod:`lfring.depth.estimate`); the photo-consistency
costs live in :mod:`lfring.depth.costs` and the engines in :mod:`lfring.depth.engines`, one
module each, each with its NumPy reference and torch twin, registered in :data:`COSTS` and
:data:`ENGINES`.
"""

from lfring.depth.aggregation import AGGREGATIONS
from lfring.depth.costs import COSTS
from lfring.depth.engines import ENGINES
from lfring.depth.engines.semiglobal import SGM_MIN_PLANES
from lfring.depth.estimate import estimate_depth
from lfring.depth.selection import DepthResult

__all__ = ["AGGREGATIONS", "COSTS", "ENGINES", "SGM_MIN_PLANES", "DepthResult", "estimate_depth"]
