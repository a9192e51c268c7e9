"""The record of one depth engine: what turns a planned sweep into a depth map.

An engine runs the sweep (:func:`lfring.depth.sweep.run_sweep`) and whatever selection,
optimisation and refinement it adds, and hands each pixel's hypothesis index and confidence to a
:class:`lfring.depth.selection.Finisher`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["DepthEngine"]


@dataclass(frozen=True)
class DepthEngine:
    """One depth engine (a ``method`` of :func:`lfring.estimate_depth`).

    Attributes
    ----------
    name : str
    summary : str
        One line for help texts.
    run : callable
        ``run(views, calibration, plan, settings, finisher, progress)`` -> dict of the fields it
        adds to the :class:`lfring.DepthResult` (the finisher holds the rest).
    default_cost : str
        The cost it uses when none is asked for.
    lcn_aggregate_px : int
        The aggregation window of the 'lcn' costs when none is asked for.
    whole_volume : bool
        It holds the whole cost volume (costs that choose over it need that).
    options : frozenset of str
        The engine-specific options of ``estimate_depth`` it reads ('paths', 'consistency').
    cell_bytes : int
        Host memory its cost volumes take at least, per pixel and hypothesis, at its peak: a call
        that would need more than the system has free is refused before it starts. 0 where the
        memory does not grow with the hypotheses (a streamed sweep).
    call_cell_bytes : callable, optional
        ``call_cell_bytes(calibration, plan, settings, view_shape)`` -> its ``cell_bytes`` for
        one call, where that depends on the call (an engine whose compact passes do not serve
        every call); ``cell_bytes`` when not given.
    device_frames : bool
        On the torch backend, where its GPU kernels run on the device
        (:func:`lfring.core.backend.kernels_run_on`), ``run`` also takes one frame's views
        as a float32 tensor on the device with a :class:`lfring.depth.engines.gpu.DeviceFinisher`,
        and leaves its maps there: batches of frames stay on the device.
    """

    name: str
    summary: str
    run: Callable
    default_cost: str
    lcn_aggregate_px: int
    whole_volume: bool = False
    options: frozenset = frozenset()
    cell_bytes: int = 0
    call_cell_bytes: Callable | None = None
    device_frames: bool = False

    def bytes_per_cell(self, calibration, plan, settings, view_shape) -> int:
        """Host memory per pixel and hypothesis of one call (see ``cell_bytes``)."""
        if self.call_cell_bytes is None:
            return self.cell_bytes
        return self.call_cell_bytes(calibration, plan, settings, view_shape)
