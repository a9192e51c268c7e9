"""Photo-consistency costs of the plane sweep, one module per cost (or family), each holding its
NumPy reference and torch twin, registered here in :data:`COSTS`.

A new cost is a module that defines a :class:`lfring.depth.costs.base.DepthCost` and one line
below that registers it; :func:`lfring.estimate_depth` looks costs up by name.
"""

from lfring.core.registry import Registry
from lfring.depth.costs.base import DepthCost
from lfring.depth.costs.differences import SAD, SAD_OCCLUSION, SSD
from lfring.depth.costs.lcn import LCN
from lfring.depth.costs.lcn_halves import LCN_HALVES
from lfring.depth.costs.lcn_occlusion import LCN_OCCLUSION
from lfring.depth.costs.zncc import ZNCC

__all__ = ["COSTS", "DepthCost", "as_cost"]

COSTS = Registry("cost")
for _cost in (LCN, LCN_HALVES, LCN_OCCLUSION, ZNCC, SAD, SSD, SAD_OCCLUSION):
    COSTS.register(_cost.name, _cost)


def as_cost(cost) -> DepthCost:
    """A cost given by name (looked up in :data:`COSTS`) or as its record."""
    return cost if isinstance(cost, DepthCost) else COSTS.lookup(cost)
