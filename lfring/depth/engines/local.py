"""The local engine: winner-take-all on each pixel's aggregated cost alone, streamed (memory does
not grow with the number of hypotheses); faster than the semi-global engine on small frames (not
on large views over many planes), and exact where the texture is good."""

from __future__ import annotations

from lfring.depth.costs.lcn import LCN_AGGREGATE_PX
from lfring.depth.engines.base import DepthEngine
from lfring.depth.sweep import run_sweep

__all__ = ["LOCAL", "run_local"]


def run_local(views, calibration, plan, settings, finisher, progress) -> dict:
    """The running minimum of the sweep straight into the finisher."""
    run_sweep(views, calibration, plan, settings, on_strip=finisher, on_rows=progress.rows(0.0, 1.0))
    progress.done()
    return {}


LOCAL = DepthEngine(
    name="local",
    summary="winner-take-all on each pixel's aggregated cost, streamed: fast on small frames, memory flat in the planes",
    run=run_local,
    default_cost="lcn",
    lcn_aggregate_px=LCN_AGGREGATE_PX,
)
