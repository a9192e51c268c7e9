"""The pipeline of one frame, as a batch worker runs it: load, check, split, refocus, depth,
all-in-focus and viewer, each output encoded in memory and handed back as bytes.

:func:`process_frame` runs in worker processes (on this machine or on a Dask cluster) and never
writes into the output folder: the process that runs the batch does the only writes, so every
write is atomic and no output escapes the folder, whatever the workers do.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lfring.batch.settings import BatchSettings, all_in_focus_from_depth_map, depth_label
from lfring.core.signals import interrupt_behind
from lfring.errors import DepthRangeError, InvalidInputError, LfringError, LfringWarning
from lfring.io.readers import frame_size

__all__ = ["REFOCUSER_CACHE_SIZE", "FrameResult", "process_frame"]

REFOCUSER_CACHE_SIZE = 32
"""Refocusers a worker process keeps (one per settings, calibration, depth and frame size)
before it drops them all and starts again."""


@dataclass
class FrameResult:
    """What a worker sends back for one frame: encoded files or an error, and timings."""

    input: str
    ok: bool
    files: dict[str, bytes] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    error: str | None = None
    worker: str = ""
    left_out: str = ""
    """Why a frame that is no scene to process was left out (a flat field), else ''."""


class _LeftOut(Exception):
    """A frame that is not to be processed, and not an error: a flat field."""


_WORKER_CACHE: dict = {}


def _worker_calibration(settings: BatchSettings, size_wh):
    if settings.calibration is not None:
        return settings.calibration, settings.calibration_name
    key = ("default", tuple(size_wh))
    if key not in _WORKER_CACHE:
        from lfring.calibration.defaults import default_calibration

        _WORKER_CACHE[key] = default_calibration(tuple(size_wh))
    return _WORKER_CACHE[key]


def _refocuser(cal, cal_name: str, depth_m: float, settings: BatchSettings, view_shape):
    """Per worker process: one Refocuser per (settings, calibration, depth, frame size), reused
    for every frame (a folder of frames at one depth pays the geometry once). Keyed by content,
    not identity: every task brings its own unpickled copy of the settings."""
    from lfring.focus import Refocuser

    key = ("refocuser", settings.key(), cal_name, depth_m, tuple(view_shape))
    r = _WORKER_CACHE.get(key)
    if r is None:
        if sum(k[0] == "refocuser" for k in _WORKER_CACHE) >= REFOCUSER_CACHE_SIZE:
            for k in [k for k in _WORKER_CACHE if k[0] == "refocuser"]:
                del _WORKER_CACHE[k]
        r = _WORKER_CACHE[key] = Refocuser(cal, depth_m, reference=settings.reference, view_shape=view_shape,
                                           interpolation=settings.interpolation)
    return r


def process_frame(input_path: str, settings: BatchSettings, outputs: dict[str, str] | None = None) -> FrameResult:
    """Run the batch pipeline on one frame; never raises for a bad frame.

    Returns a :class:`FrameResult` whose ``files`` maps each output kind of
    :meth:`BatchSettings.outputs` to the encoded file's bytes; on failure ``ok`` is False and
    ``error`` says why in one line; a flat field (which the frame check recognises) is not
    processed: ``ok`` is False and ``left_out`` says so. Ctrl-C is no bad frame: it stops the run,
    as a KeyboardInterrupt, even where Python wrapped it in another error.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    worker = f"{socket.gethostname()}:{os.getpid()}"
    outputs = outputs if outputs is not None else settings.outputs(Path(input_path).stem)
    caught: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as wlist:
            warnings.simplefilter("always")
            files, info = _process(input_path, settings, outputs, timings)
            caught = [str(w.message) for w in wlist]
    except _LeftOut as exc:
        timings["total"] = time.perf_counter() - t_start
        return FrameResult(input_path, False, timings_s=timings, worker=worker, left_out=str(exc))
    except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the batch; the error is kept by name
        return _failed(input_path, exc, timings, t_start, worker)
    if caught:
        info["warnings"] = sorted(set(caught))
    timings["total"] = time.perf_counter() - t_start
    return FrameResult(input_path, True, files=files, info=info, timings_s=timings, worker=worker)


def _failed(input_path, exc: Exception, timings, t_start, worker) -> FrameResult:
    """The record of a frame that failed with ``exc``, or the stop that ``exc`` stands for, raised:
    a Ctrl-C wrapped by Python 3.10 and 3.11 during an import, or turned into another error by a
    library (:func:`lfring.core.signals.interrupt_behind`), stops the run."""
    stop = interrupt_behind(exc)
    if stop is not None:
        raise stop from None
    timings["total"] = time.perf_counter() - t_start
    if isinstance(exc, DepthRangeError):  # the depth method's message names estimate_depth's parameters, not the batch's
        error = f"{input_path}: {_narrow_range(exc)}"
    elif isinstance(exc, (LfringError, OSError, ValueError, MemoryError)):
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        error = msg if isinstance(exc, LfringError) else f"{type(exc).__name__}: {msg}"
        if input_path not in error:
            error = f"{input_path}: {error}"
    else:
        error = f"unexpected {type(exc).__name__}: {exc}"
    return FrameResult(input_path, False, timings_s=timings, error=error, worker=worker)


def _process(input_path, settings: BatchSettings, outputs, timings) -> tuple[dict[str, bytes], dict]:
    from lfring.focus import all_in_focus
    from lfring.io.demosaic import demosaic
    from lfring.io.levels import load_frame
    from lfring.io.writers import encode_file, encode_float_tiff, encode_image
    from lfring.views import split_views

    t = time.perf_counter()
    # The calibration first where the file's header tells the frame's size: its pattern and
    # levels stand in for those the frame lacks, as they do for the settings' calibration.
    picked = settings.calibration is None
    size = frame_size(input_path) if picked else None  # (0, 0): float samples, the frame's own error says so
    cal, cal_name = _worker_calibration(settings, size) if not picked or size not in (None, (0, 0)) else (None, None)
    frame, notes = load_frame(input_path, pattern=settings.pattern, black_level=settings.black_level,
                              white_level=settings.white_level, calibration=cal, only_fitting=picked)
    for level, message in notes:
        if level >= logging.WARNING:
            warnings.warn(message, LfringWarning, stacklevel=2)
    if cal is None:  # the header did not tell the frame's size (camera RAW)
        cal, cal_name = _worker_calibration(settings, frame.shape[::-1])
    image = demosaic(frame)
    cal.check_frame(image.shape, what=f"frame {input_path}")
    if settings.check_frames:
        from lfring.check import check_frame

        checked = check_frame(image, cal)
        if checked.flat_field:
            raise _LeftOut("a flat field (a white frame of the camera, no scene to process)")
        if not checked.ok:
            raise InvalidInputError(f"{input_path}: {checked.message}")
    views = split_views(image, cal)  # the calibration's lens distortion undone, its flat field divided
    if not np.all(np.isfinite(views)):
        raise InvalidInputError(f"{input_path}: the frame holds NaN or infinite values")
    timings["load"] = time.perf_counter() - t
    info: dict = {"calibration": cal_name, "frame_size_px": [int(image.shape[1]), int(image.shape[0])]}
    arrays: dict[str, np.ndarray] = {}

    from lfring.focus import METHODS

    refocus = [z for z in settings.refocus_m if f"refocus_{depth_label(z)}m" in outputs]
    method = METHODS[settings.refocus_method]
    needs_depth = "depth" in method.options  # a method that renders from the frame's depth map
    depth_res = None
    depth_range = None
    # The all-in-focus image from the frame's depth map when the settings make one (see
    # all_in_focus_from_depth_map), whether or not their refocused images are still to make.
    aif_depth = "all_in_focus" in outputs and all_in_focus_from_depth_map(settings.depth, settings.refocus_m,
                                                                           settings.refocus_method)
    if settings.depth or settings.viewer or (needs_depth and refocus) or aif_depth:
        # Every depth map of the frame spans one range, by depth-aware refocusing's rule (as
        # lfring depth's and lfring refocus's): a range given as the calibration's own makes the
        # same maps and images as none, which the outputs' keys rely on.
        from lfring.focus.depth_aware import estimation_range

        depth_range = estimation_range(cal, settings.zmin_m, settings.zmax_m, reference=settings.reference)
        info["depth_range_m"] = [float(depth_range[0]), float(depth_range[1])]
    depth_wanted = {"depth", "confidence", "depth_preview", "all_in_focus"} & set(outputs)
    # The frame's one depth map: for its own outputs and the viewer with --depth, for depth-aware
    # refocusing and for the all-in-focus image (the same map either way).
    if (settings.depth and (depth_wanted or "viewer" in outputs)) or (needs_depth and refocus) or aif_depth:
        from lfring.depth import estimate_depth

        t = time.perf_counter()
        depth_res = estimate_depth(views, cal, zmin_m=depth_range[0], zmax_m=depth_range[1], num_planes=settings.planes,
                                   reference=settings.reference, method=settings.depth_method)
        timings["depth"] = time.perf_counter() - t
        info["depth_hypotheses"] = len(depth_res.depths_m)
        info["depth_step_px"] = float(depth_res.step_px)
        ok = np.isfinite(depth_res.depth_m) & (depth_res.confidence >= settings.min_confidence)
        info["confident_fraction"] = float(ok.mean())
        if ok.any():
            info["depth_median_m"] = float(np.median(depth_res.depth_m[ok]))

    renderer = None
    if aif_depth:  # the all-in-focus image's renderer of the map, which depth-aware refocusing reuses
        from lfring.focus.depth_aware import DEPTH_AWARE, depth_of_field

        t = time.perf_counter()
        renderer = depth_of_field(views, cal, depth=depth_res, reference=settings.reference)
        timings["depth_of_field"] = time.perf_counter() - t
    t = time.perf_counter()
    finish = None
    if refocus or settings.viewer:
        info.update(_refocus_record(cal, settings))
    if refocus and method.prepare is not None:
        reuse = renderer is not None and method is DEPTH_AWARE  # another method takes the map itself
        finish = _finisher(views, cal, settings, renderer if reuse else depth_res, info["aperture"], timings)
    for z in refocus:
        sharp = _refocuser(cal, cal_name, z, settings, views.shape[1:3])(views)
        arrays[f"refocus_{depth_label(z)}m"] = sharp if finish is None else finish(sharp, z)
    timings["refocus"] = time.perf_counter() - t

    if "all_in_focus" in outputs:
        t = time.perf_counter()
        if aif_depth:
            img, _ = all_in_focus(views, cal, depth_map_m=renderer, reference=settings.reference)
        else:
            zs = list(settings.refocus_m) if len(settings.refocus_m) > 1 else None
            img, _ = all_in_focus(views, cal, zs, reference=settings.reference)
        arrays["all_in_focus"] = img
        timings["all_in_focus"] = time.perf_counter() - t

    # Encode in memory and hand back bytes: the caller (maybe on another machine) does the only
    # writes into OUTDIR.
    t = time.perf_counter()
    files: dict[str, bytes] = {}
    for kind, img in arrays.items():
        files[kind] = encode_file(encode_image(img, settings.bit_depth, settings.encoding), Path(outputs[kind]).suffix)
    if depth_res is not None:
        if "depth" in outputs:
            files["depth"] = encode_float_tiff(depth_res.depth_m)
        if "confidence" in outputs:
            files["confidence"] = encode_float_tiff(depth_res.confidence)
        if "depth_preview" in outputs:
            files["depth_preview"] = _depth_preview_png(depth_res, settings, depth_range, Path(input_path).name)
    timings["encode"] = time.perf_counter() - t
    if settings.viewer:
        from lfring.viewer import viewer_html

        t = time.perf_counter()
        stack = {"method": settings.refocus_method}
        if "aperture" in method.options:
            stack["aperture"] = info["aperture"]
        # The batch's own depth map (depth), else the viewer's default one: a map made only for
        # refocusing follows the batch's depth method, the viewer's is always semi-global.
        own = depth_res if settings.depth else None
        files["viewer"] = viewer_html(views, cal, zmin_m=depth_range[0], zmax_m=depth_range[1], reference=settings.reference,
                                      depth=own, num_planes=None if own is not None else settings.planes,
                                      min_confidence=settings.min_confidence, title=Path(input_path).name,
                                      metadata={"input": str(input_path), "calibration": cal_name, **_stack_record(info)},
                                      **stack).encode("utf-8")
        timings["viewer"] = time.perf_counter() - t
    missing = set(outputs) - set(files)
    if missing:  # pragma: no cover - a programming error, not a bad frame
        raise RuntimeError(f"outputs not produced: {sorted(missing)}")
    return files, info


def _narrow_range(exc: DepthRangeError) -> str:
    """A depth range too narrow to estimate depth over, in the words of :class:`BatchSettings`."""
    return exc.narrow("widen it" if exc.planes_needed is None
                      else f"widen it or give planes >= {exc.planes_needed}")


def _refocus_record(cal, settings: BatchSettings) -> dict:
    """What the frame's record says of the method and aperture that made its refocused images
    (and the viewer's focal stack): for a method with a depth of field ('depth-aware') the
    aperture itself, resolved from the f-number when one was given; shift-and-add has none (its
    copies sit on the rim of the aperture the views span)."""
    from lfring.focus import METHODS, resolve_aperture

    if "aperture" not in METHODS[settings.refocus_method].options:
        return {"refocus_method": settings.refocus_method, "aperture": None}

    out = {"refocus_method": settings.refocus_method,
           "aperture": resolve_aperture(cal, aperture=settings.aperture, f_number=settings.f_number)}
    if settings.f_number is not None:
        out["f_number"] = settings.f_number
    return out


def _stack_record(info: dict) -> dict:
    """The viewer's metadata entries of :func:`_refocus_record`."""
    return {k: info[k] for k in ("refocus_method", "aperture", "f_number") if k in info}


def _finisher(views, cal, settings: BatchSettings, depth, aperture, timings: dict):
    """The refocusing method's ``finish(sharp, z)`` for one frame (:class:`lfring.focus.base.RefocusMethod`),
    made once for all its depths; a method that renders from a depth map gets the frame's
    (``depth``: the estimate, or a renderer already made from it)."""
    from lfring.focus import METHODS

    method = METHODS[settings.refocus_method]
    t = time.perf_counter()
    options = {}
    if "depth" in method.options:
        options["depth"] = depth
    if "aperture" in method.options:
        options["aperture"] = aperture
    finish = method.prepare(views, cal, settings.reference, **options)
    timings["refocus_prepare"] = time.perf_counter() - t
    return finish


def _depth_preview_png(depth_res, settings: BatchSettings, depth_range, name: str) -> bytes:
    """The depth preview's PNG bytes, made in memory, its colour bar over ``depth_range``."""
    from lfring.depth.io import depth_preview_png

    return depth_preview_png(depth_res.depth_m, confidence=depth_res.confidence, zmin_m=depth_range[0],
                             zmax_m=depth_range[1], title=f"{name}: depth (m)", min_confidence=settings.min_confidence)
