"""Depth from the views: plane sweep with confidence (SPEC 6), metrics and outputs."""

from lfring.depth.sweep import AGGREGATIONS, COSTS, DepthResult, estimate_depth

__all__ = ["AGGREGATIONS", "COSTS", "DepthResult", "estimate_depth"]
