"""Plane-sweep depth over the views: the entry point, which checks the arguments, plans the sweep
and hands it to the engine asked for.

For every hypothesis Z (evenly spaced in 1/(Z - z0), at most one pixel of view motion apart by
default; :mod:`lfring.depth.hypotheses`) every view is warped into the reference frame with
H_ref_from_view(Z), the warped views are compared (:mod:`lfring.depth.costs`), the cost is
aggregated spatially (:mod:`lfring.depth.aggregation`), and an engine
(:mod:`lfring.depth.engines`) turns the costs into each pixel's hypothesis and confidence. A
parabola through three costs gives the sub-hypothesis depth; the cost curve's distinctness gives
the confidence. Costs and engines are looked up by name in :data:`lfring.depth.costs.COSTS` and
:data:`lfring.depth.engines.ENGINES`.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.backend import check_backend, require_torch, resolve_device
from lfring.core.memory import check_free_memory, memory_words
from lfring.core.transfer import (check_frames, count_levels, download, download_maps, frames_dtype, is_tensor,
                                  normalised, to_device)
from lfring.core.protocols import check_calibration
from lfring.core.threads import run_threads
from lfring.core.validate import (check_bool, check_callable, check_choice, check_fraction, check_int, check_odd_px,
                                  check_threads)
from lfring.core.viewstack import check_views
from lfring.depth.aggregation import AGGREGATIONS
from lfring.depth.costs import COSTS
from lfring.depth.engines import ENGINES
from lfring.depth.plan import DEPTH_TAPER, JUDGED_MIN_PLANES, DepthSettings, Progress, plan_sweep
from lfring.depth.sgm import check_paths
from lfring.depth.selection import DepthResult, Finisher
from lfring.errors import InvalidInputError

__all__ = ["estimate_depth"]


def estimate_depth(
    views,
    calibration,
    *,
    zmin_m: float,
    zmax_m: float,
    num_planes: int | None = None,
    reference="center",
    backend: str = "numpy",
    device=None,
    levels=None,
    cost: str | None = None,
    aggregation: str = "box",
    window_px: int = 9,
    aggregate_px: int | None = None,
    min_views: int = 2,
    rim_taper: float = DEPTH_TAPER,
    threads: int | None = None,
    method: str = "sgm",
    paths: int = 4,
    consistency: bool | None = None,
    progress=None,
) -> DepthResult:
    """Metric depth and confidence by plane sweep over the views.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        Cut with the calibration's layout (:func:`lfring.split_views`). The torch backend also
        takes a batch (B, V, h, w, C), torch tensors, and raw counts (uint8, uint16; see
        ``levels``): a batch is estimated in one go and its maps come as (B, h, w); tensors give
        a result of tensors on the device, NumPy arrays one of arrays.
    calibration : RingCalibration
    zmin_m, zmax_m : float
        Depth range in metres from the main lens; zmin_m must lie beyond z0.
    num_planes : int, optional
        Number of hypotheses, evenly spaced in 1/(Z - z0). By default just enough that no view
        pixel moves more than one pixel between neighbours (``step_px`` reports it).
    reference : 'center' or int
        Frame of the depth map.
    backend : {'numpy', 'torch'}, device : str, optional
        The torch backend is the GPU path: on ``device`` (CUDA when present by default; the
        device of tensor views) the 'sgm' method runs as fused Triton kernels, device-resident
        from the uploaded views to the maps, which come back in one copy
        (:mod:`lfring.depth.engines.gpu`); the other methods, and every method on a CPU device,
        run the same algorithms with torch and kornia.
    levels : (black, white), optional
        Raw-count views (torch backend): they travel to the device as integers and become
        ``(count - black) / (white - black)`` there; by default black 0 and white the dtype's
        largest count. Float views take none.
    cost : str, optional
        Photo-consistency, one of :data:`lfring.depth.costs.COSTS`; by default the engine's
        ('lcn-halves' for 'sgm', 'lcn' for 'local'). 'lcn': the variance across views of their
        luminances normalised by the local mean and contrast over ``window_px`` (normalised once
        per view, before the sweep: the fastest, and blind to each view's vignetting).
        'lcn-halves' (engines that hold the whole volume): the same, and where no depth suits all
        views but the views on one side of the reference agree much better (a depth edge hides
        the background from the views on the other side), that side's cost (from three views on,
        otherwise 'lcn'); it costs a second volume during the sweep. 'lcn-occlusion': over each
        aggregation window, the least of the 'lcn' cost and the costs without one view (from
        three views on). 'zncc', 'sad', 'ssd', 'sad-occlusion' compare the warped luminances
        divided by their wide local mean: one minus their mean zero-normalised
        cross-correlation with the mean over ``window_px``, the absolute or squared deviation
        from their mean, or the absolute deviation without the view deviating most per pixel.
    aggregation : {'box', 'guided'}
        Spatial aggregation of each cost slice over ``aggregate_px``: a box, or an edge-aware
        guided filter (guide: the reference view, or for 'center' the views' mean refocused at
        the middle hypothesis).
    window_px : int
        Odd window of the normalisation ('lcn') or of the correlation ('zncc').
    aggregate_px : int, optional
        Odd window of the aggregation: by default, for the 'lcn' costs, the engine's (a small
        box for 'sgm', whose optimisation does the rest of the smoothing; a wider one for
        'local'); ``window_px`` for the other costs.
    min_views : int
        From 1 to the number of views: pixels seen by fewer views get NaN.
    rim_taper : float
        Fraction of each view's disc radius, in [0, 1], over which its weight rises from 0 to 1
        (:func:`lfring.core.viewstack.view_masks`); a view counts as the sum of its weights
        towards ``min_views``. The default (``lfring.depth.plan.DEPTH_TAPER``) measures every
        pixel that two views see; the refocusing taper (``lfring.core.viewstack.TAPER``) trusts
        the dark periphery of the discs less, as inspection does.
    threads : int, optional
        Threads of the sweep and of the optimisation; by default OpenCV's thread count.
    method : str
        The engine, one of :data:`lfring.depth.engines.ENGINES`. 'sgm' (default): the whole cost
        volume is optimised semi-globally (:mod:`lfring.depth.engines.semiglobal`: along
        ``paths`` scan lines a penalty for every change of depth, lowered across image edges),
        which fills weak texture and keeps gross outliers away, with shiftable windows so that a
        surface's texture does not spread its depth over the pixels beside it. Its float32
        reference ('sgm-reference') holds the cost volume three times over at its peak (the
        cost, its eroded copy and the optimised one); the default's fused passes hold it twice
        in 16 bits (three times, with its eroded copy, while that takes at most
        ``lfring.depth.engines.fused.ERODED_VOLUME_BYTES``), and keep those volumes with the
        calibration object for its next call of the same size when they take at most
        ``lfring.depth.engines.fused.KEEP_VOLUMES_BYTES``. The fused passes serve the NumPy
        backend with an 'lcn' cost of all views, box aggregation, 4 paths and views that every
        hypothesis moves by a shift (``lfring.depth.engines.fused.fused_shifts``); other calls
        of 'sgm' run the reference's float32 passes (and are weighed against the free memory
        as those).
        It needs hypotheses more than one pixel of view motion apart (``InvalidInputError``
        otherwise). The result is refined by an edge-aware weighted median;
        ``DepthResult.depth_filled_m`` also fills the unconfident pixels
        (:mod:`lfring.depth.refine`). 'local': winner-take-all on the aggregated cost of each
        pixel alone, streamed (memory does not grow with the number of hypotheses): faster on
        small frames (not on large views over many planes), and exact where the texture is good.
    paths : {4, 8}
        Scan paths of 'sgm' (the other engines refuse 8).
    consistency : bool, optional
        'sgm' only: estimate the map again from the view farthest from the reference and make
        unknown (NaN) the pixels whose two answers disagree by more than one pixel of motion:
        the left-right check of stereo, which finds the pixels the other view cannot see. With
        the check, the pixels whose confidence is below ``lfring.depth.refine.MIN_CONFIDENCE``
        are unknown too (without it they keep the optimisation's answer, which their scan lines
        gave them). It doubles the time. ``depth_filled_m`` fills the rejected pixels from the
        farther side along the baseline (they are mostly background hidden from the other view
        by a nearer surface). By default on for two views (a pixel occluded in the other view
        has no information at all) and off for more (a pixel hidden from one view is still
        measured by the others, and a single second frame would reject it).
    progress : callable, optional
        Called as ``progress(fraction)`` (0 to 1) as the work advances, possibly from worker
        threads (the calls are serialised): for a progress bar.

    Returns
    -------
    DepthResult
        Its maps (h, w), or (B, h, w) for a batch; torch tensors on the device for tensor views.

    Notes
    -----
    With c(i) the aggregated cost, i* = argmin c and a parabola through c(i*-1), c(i*), c(i*+1),
    the refined index is ``i* + (c(i*-1) - c(i*+1)) / (2 (c(i*-1) - 2 c(i*) + c(i*+1)))``; the
    depth follows from linear interpolation in 1/(Z - z0). The confidence is
    ``1 - c(i*) / c2`` with c2 the lowest cost more than one pixel of view motion from i*.

    Examples
    --------
    The bundled scene of the twin (data/synthetic, paths relative to the repository root): a
    cup at 0.3 m, a book at 0.5 m, a chessboard at 1 m. The fast 'local' method; the rows
    300:400, columns 450:550 of the centre frame lie on the book:

    >>> import numpy as np
    >>> import lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
    >>> result = lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, method="local")
    >>> result.depth_m.shape, result.depth_m.dtype
    ((705, 705), dtype('float32'))
    >>> round(float(np.nanmedian(result.depth_m[300:400, 450:550])), 2)  # the book, metres
    0.5
    """
    backend = check_backend(backend)
    engine = ENGINES.lookup(method)
    depth_cost = COSTS.lookup(engine.default_cost if cost is None else cost)
    if depth_cost.halves and not engine.whole_volume:
        holders = ", ".join(f"method={e.name!r}" for e in ENGINES.values() if e.whole_volume)
        raise InvalidInputError(f"cost {depth_cost.name!r} chooses per pixel over the whole cost volume: it needs {holders}")
    check_choice(aggregation, "aggregation", AGGREGATIONS)
    paths = check_paths(paths)
    consistency = check_bool(consistency, "consistency", allow_none=True, hint=" (on for two views)")
    if "paths" not in engine.options and (paths != 4 or consistency):
        owners = ", ".join(f"method={e.name!r}" for e in ENGINES.values() if "paths" in e.options)
        raise InvalidInputError(f"paths and consistency belong to {owners}")
    check_odd_px(window_px, "window_px")
    if aggregate_px is not None:
        check_odd_px(aggregate_px, "aggregate_px")
    threads = check_threads(threads)
    check_int(num_planes, "num_planes", minimum=JUDGED_MIN_PLANES, allow_none=True, hint=" (None: the default spacing)")
    check_callable(progress, "progress", what="a callable progress(fraction)")
    check_calibration(calibration)
    rim_taper = check_fraction(rim_taper, "rim_taper", hint=" (a fraction of the disc radius)")
    if backend == "torch" and (levels is not None or is_tensor(views) or np.ndim(views) == 5
                               or np.asarray(views).dtype != np.float32):
        return _estimate_frames(views, calibration, engine, depth_cost, levels, progress, dict(
            zmin_m=zmin_m, zmax_m=zmax_m, num_planes=num_planes, reference=reference, device=device,
            aggregation=aggregation, window_px=window_px, aggregate_px=aggregate_px, min_views=min_views,
            rim_taper=rim_taper, threads=threads, paths=paths, consistency=consistency))
    if levels is not None:
        raise InvalidInputError("levels are the black and white counts of integer views on the torch backend")
    if backend == "numpy" and device is not None:
        raise InvalidInputError(f"device={device!r} is for backend='torch'; the NumPy backend runs on this machine's "
                                "cores")
    arr = check_views(views)
    calibration.check_fits(arr.shape)
    _check_windows(window_px, aggregate_px, arr.shape[1:3])
    min_views = check_int(min_views, "min_views", minimum=1, maximum=arr.shape[0], hint=f" (there are {arr.shape[0]} views)")
    threads = _thread_count(threads)
    if not _all_finite(arr, threads):
        raise InvalidInputError("views contain NaN or infinite values")
    plan = plan_sweep(arr, calibration, zmin_m, zmax_m, num_planes, reference, rim_taper)
    if aggregate_px is None:
        aggregate_px = engine.lcn_aggregate_px if depth_cost.lcn else window_px
    settings = DepthSettings(cost=depth_cost, aggregation=aggregation, window_px=window_px, aggregate_px=aggregate_px,
                             min_views=min_views, threads=threads,
                             backend=backend, device=device, paths=paths, consistency=consistency)
    finisher = Finisher(plan.depths, calibration.depth_origin_m, arr.shape[1:3], min_views)
    # The host holds the volumes, but for an engine whose kernels run on the torch device.
    on_device = backend == "torch" and engine.device_frames and _runs_on_device(device, plan)
    need = 0 if on_device else _check_memory(engine, calibration, plan, settings, arr.shape[1:3])
    try:
        extra = engine.run(arr, calibration, plan, settings, finisher, Progress(progress, arr.shape[1]))
    except MemoryError:
        raise InvalidInputError(f"{_memory_words(engine, len(plan.depths), arr.shape[1:3], need)} ran out of memory: "
                                f"{_MEMORY_REMEDY}") from None
    return finisher.result(depths_m=plan.depths, step_px=plan.step_px, reference=plan.reference, cost=depth_cost.name,
                           aggregation=aggregation, method=engine.name, **extra)


_MEMORY_REMEDY = ("give fewer num_planes, narrow zmin_m..zmax_m, or use method='local' (its memory does not grow "
                  "with the hypotheses)")


def _memory_words(engine, n: int, shape, need: int) -> str:
    words = f"method={engine.name!r} over {n} depth hypotheses on {shape[1]} x {shape[0]} px views"
    return words + (f" (at least {memory_words(need)})" if need else "")


# The narrowest normalisation window: every cost divides by a local mean (and 'lcn' by a local
# contrast) over ``window_px``, and over one pixel that leaves every view alike.
MIN_WINDOW_PX = 3


def _check_windows(window_px, aggregate_px, shape_hw) -> None:
    """The windows against the views' size (h, w), once it is known (:func:`check_odd_px`)."""
    check_odd_px(window_px, "window_px", within=shape_hw)
    if window_px < MIN_WINDOW_PX:
        raise InvalidInputError(f"window_px must be at least {MIN_WINDOW_PX}: the costs normalise each view by its local "
                                f"mean over the window, and over one pixel every view looks alike; got {window_px}")
    if aggregate_px is not None:
        check_odd_px(aggregate_px, "aggregate_px", within=shape_hw)


def _runs_on_device(device, plan) -> bool:
    from lfring.depth.engines import gpu

    return gpu.engine_runs_on(resolve_device(device), plan)


def _check_memory(engine, calibration, plan, settings, shape) -> int:
    """The bytes the engine's cost volumes take at least for the plan's hypotheses on views of
    ``shape``; refused where that is more than the system has free (where it cannot say, the
    call goes ahead)."""
    n = len(plan.depths)
    need = engine.bytes_per_cell(calibration, plan, settings, tuple(shape)) * n * int(shape[0]) * int(shape[1])
    check_free_memory(need, _memory_words(engine, n, shape, need), _MEMORY_REMEDY)
    return need


def _thread_count(threads) -> int:
    """The threads of a call: OpenCV's thread count when None is given."""
    return max(1, cv2.getNumThreads()) if threads is None else threads


def _all_finite(arr: np.ndarray, threads: int) -> bool:
    """Whether every value of the views ``arr`` is finite (one view per task on ``threads``)."""
    finite = [True] * len(arr)

    def check(k: int) -> None:
        finite[k] = bool(np.isfinite(arr[k]).all())

    run_threads([lambda k=k: check(k) for k in range(len(arr))], threads)
    return all(finite)


def _estimate_frames(views, calibration, engine, depth_cost, levels, progress, options) -> DepthResult:
    """The torch backend's path for a batch (B, V, h, w, C), tensors and raw counts: the views go
    to the device once (integers as integers) and every frame is estimated there; an engine that
    runs on the device (``DepthEngine.device_frames``) keeps its maps there, the others take each
    frame on the host. The maps are stacked and, for NumPy views, copied to the host once."""
    torch = require_torch()
    from lfring.depth.engines import gpu

    tensor_in = is_tensor(views)
    if not tensor_in:
        views = np.asarray(views)
    shape, single = check_frames(views)
    b, v, h, w, c = shape
    _check_windows(options["window_px"], options["aggregate_px"], (h, w))
    offset, scale = count_levels(frames_dtype(views), levels)
    dev = resolve_device(options["device"] if options["device"] is not None or not tensor_in else views.device)
    raw = (views if tensor_in else to_device(views, dev)).to(dev).reshape(shape)
    frames = normalised(raw, offset, scale)
    calibration.check_fits(shape[1:])
    min_views = check_int(options["min_views"], "min_views", minimum=1, maximum=v, hint=f" (there are {v} views)")
    if not bool(torch.isfinite(frames).all()):
        raise InvalidInputError("views contain NaN or infinite values")
    plan = plan_sweep(frames[0], calibration, options["zmin_m"], options["zmax_m"], options["num_planes"],
                      options["reference"], options["rim_taper"])
    aggregate_px = options["aggregate_px"]
    if aggregate_px is None:
        aggregate_px = engine.lcn_aggregate_px if depth_cost.lcn else options["window_px"]
    threads = options["threads"]
    settings = DepthSettings(cost=depth_cost, aggregation=options["aggregation"], window_px=options["window_px"],
                             aggregate_px=aggregate_px, min_views=min_views,
                             threads=_thread_count(threads), backend="torch",
                             device=dev, paths=options["paths"], consistency=options["consistency"])
    on_device = engine.device_frames and gpu.engine_runs_on(dev, plan)
    if not on_device:  # the host holds the volumes
        _check_memory(engine, calibration, plan, settings, (h, w))
    maps, extras = [], []
    for k in range(b):
        args = (plan.depths, calibration.depth_origin_m, (h, w), min_views)
        finisher = gpu.DeviceFinisher(*args) if on_device else Finisher(*args)
        report = Progress(None if progress is None else (lambda f, k=k: progress((k + f) / b)), h)
        frame = frames[k] if on_device else download(frames[k])
        extra = engine.run(frame, calibration, plan, settings, finisher, report)
        filled = extra.pop("depth_filled_m", None)
        maps.append([finisher.depth, finisher.conf, finisher.index] + ([] if filled is None else [filled]))
        extras.append(extra)
    if on_device:  # tensors on the device: one copy to the host for NumPy views
        stacked = [torch.stack([m[i] for m in maps]) for i in range(len(maps[0]))]
        if not tensor_in:
            stacked = download_maps(stacked)
    else:  # arrays on the host: one copy to the device for tensor views
        stacked = [np.stack([m[i] for m in maps]) for i in range(len(maps[0]))]
        if tensor_in:
            stacked = list(to_device(np.stack(stacked), dev))
    if single:
        stacked = [m[0] for m in stacked]
    fields = dict(depth_m=stacked[0], confidence=stacked[1], hypothesis_index=stacked[2])
    if len(stacked) > 3:
        fields["depth_filled_m"] = stacked[3]
    return DepthResult(depths_m=plan.depths, step_px=plan.step_px, reference=plan.reference, cost=depth_cost.name,
                       aggregation=options["aggregation"], method=engine.name, **fields, **extras[0])
