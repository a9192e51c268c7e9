"""``lfring.calibrate``: from photographs of a planar target at known depths to a RingCalibration."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from lfring.calibration.build import calibration_from_plane_homographies
from lfring.calibration.ring import DEVICE_RECORD, RingCalibration
from lfring.core.lens import remap_views, undistortion_maps
from lfring.core.validate import check_bool, is_number
from lfring.errors import DeviceError, EstimationError, InvalidInputError, LfringError
from lfring.views import Layout, detect_layout, flat_field_from_frame, split_views

__all__ = ["calibrate", "check_disparity_sign", "check_fitted_origin", "load_image"]

log = logging.getLogger("lfring.calibration")

DEPTH_ORIGIN_TOL = 0.02
"""A z0 fitted to three or more planes that lies farther than this fraction of the nearest
plane's depth from the device's entrance pupil s (z0 = s for the ring) draws a warning (one
behind the main lens is refused): three planes fit the model exactly whatever their depths, so a
mislabelled depth shows only as a z0 elsewhere (benchmarks/RESULTS.md, "Calibration: a mislabelled
plane and the flat's layout")."""
DEPTH_LABEL_TOL = 0.1
"""Relative difference between how far the views move from one plane to the next and how far
the device's optics move them between the depths given, above which the calibration warns:
the optics are a design, not the built camera, so only a depth measured from the wrong point,
given for another frame or in another unit is that far off."""
UNIT_RATIO = 30.0
"""A factor between how far the views move from one plane to the next and how far the device's
optics move them between the depths given beyond which the depths are refused: no camera departs
from its design that far, another unit does (millimetres given as metres: about 1000)."""
# Largest distance (px) between where the flat frame and the targets (their mean) show a view's
# disc before the flat is said to come from another setup (the ring or the zoom moved between
# them); the views are cut where the flat shows them. The discs found on a target's texture lie
# some pixels from the flat's in the same setup (benchmarks/RESULTS.md, "Calibration: a
# mislabelled plane and the flat's layout").
FLAT_LAYOUT_TOL_PX = 10.0


def load_image(frame, *, pattern=None, black_level=None, white_level=None, method: str = "edge-aware") -> tuple[np.ndarray, str]:
    """A frame given as a path, a RawFrame or an array -> (float32 image (H, W, C), name)."""
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame, load_raw

    if isinstance(frame, (str, Path)):
        return demosaic(load_raw(frame, pattern=pattern, black_level=black_level, white_level=white_level), method=method), str(frame)
    if isinstance(frame, RawFrame):
        return demosaic(frame, method=method), str(frame.path or "frame")
    arr = np.asarray(frame)
    if arr.ndim not in (2, 3) or not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(
            f"a frame must be a path, a RawFrame or a floating (H, W[, C]) image in [0, 1], got {arr.dtype} {arr.shape}"
        )
    return arr.astype(np.float32, copy=False), "array"


def calibrate(
    frames_by_depth: dict,
    *,
    flat=None,
    layout: Layout | None = None,
    depth_origin_m: float | None = None,
    method: str = "ecc",
    reference: int = 0,
    rank1: bool = False,
    pattern: str | None = None,
    black_level=None,
    white_level=None,
    device=None,
    distortion: bool = True,
    carry_flat: bool = False,
    rotate180: bool = False,
) -> RingCalibration:
    """Calibrate refocusing in metric depth from frames of a textured planar target.

    Parameters
    ----------
    frames_by_depth : {depth_m: frame}
        Two or more frames (paths, RawFrames or float images) of a fronto-parallel textured
        target, keyed by its distance from the main lens in metres.
    flat : frame, optional
        A flat (white) frame: the layout is detected on it and the views are flat-fielded
        before alignment, which removes the views' different vignetting.
    layout : Layout, optional
        Use this layout instead of detecting one.
    depth_origin_m : float or None
        z0 of the model. None: fitted with three or more planes; with two, the entrance pupil s
        of ``device`` when one is given, else 0. For the ring z0 = s is exact; 0 makes the model
        miss by a fraction of a pixel at depths between and beyond the planes
        (benchmarks/RESULTS.md, "Calibration").
    method : {'ecc', 'sift'}
        Per-plane homographies by direct intensity alignment (ECC, initialised by phase
        correlation; no features) or by SIFT + RANSAC.
    reference : int
        View the homographies are measured into (any reference, 'center' included, can be
        asked of the result).
    rank1 : bool
        Constrain each B_k to rank 1.
    device : RingDevice, str or path, optional
        The camera's description (a built-in name or a device file too), for z0 = s with two
        planes and to check the depths given against its optics; refused when no binning of its
        sensor gives the targets' frames. The calibration keeps its record
        (:meth:`RingCalibration.device_optics`). Without it the built-in calibration of frames
        this size (if any) checks the depths, refusing only those in another unit (views moving
        :data:`UNIT_RATIO` times otherwise than the depths say).
    distortion : bool
        Estimate each view's lens distortion jointly with the homographies
        (:func:`lfring.calibration.distortion.estimate_distortion`) and keep it when it matters:
        when it changes some plane's view-to-reference map by more than
        :data:`~lfring.calibration.distortion.NEGLIGIBLE_DISTORTION_PX` beyond a homography and
        explains a good part of the views' misregistration. The homographies are then measured
        again on the undistorted views. False: the views are used as they are cut.
    carry_flat : bool
        Keep the flat frame's field (each view's vignetting) in the calibration, so that the
        views split with it are flat-fielded (needs ``flat``).
    rotate180 : bool
        The camera writes its frames rotated by 180 degrees: the detected layout undoes that
        (recorded in the calibration, so every frame split with it is turned upright). A given
        ``layout`` records its own rotation.

    Returns
    -------
    RingCalibration
        With per-plane residuals (model vs measurement) in pixels, leave-one-out errors for
        three or more planes (four or more when z0 is fitted), and the alignment diagnostics in ``provenance`` (with the
        distortion's: the views' misregistration before and after it is undone).

    Examples
    --------
    The twin's targets at 0.3 m and 1 m and its flat frame (data/synthetic, paths relative to
    the repository root), z0 from the prototype's optics: the command that made the built-in
    calibration ``twin_binned2`` (calib/README.md), which this reproduces:

    >>> import numpy as np
    >>> from lfring import RingCalibration, calibrate
    >>> from lfring.optics import load_device
    >>> cal = calibrate({0.3: "data/synthetic/target_0.3m.png", 1.0: "data/synthetic/target_1m.png"},
    ...                 flat="data/synthetic/flat.png", device=load_device("prototype"))
    >>> round(cal.depth_origin_m, 4), cal.num_views, cal.source
    (0.028, 4, 'planes')
    >>> np.round(cal.homographies(0.5)[:, :2, 2], 1).tolist()  # view shifts at 0.5 m, px
    [[58.8, 58.8], [-58.8, 58.8], [58.8, -58.8], [-58.8, -58.8]]
    >>> shipped = RingCalibration.load("twin_binned2")
    >>> float(np.abs(cal.homographies(0.5) - shipped.homographies(0.5)).max()) < 1e-3
    True
    """
    from lfring.calibration.planes import check_flat_views, estimate_plane_homographies

    if carry_flat and flat is None:
        raise InvalidInputError("carry_flat needs the flat frame (flat=...)")
    if device is not None:
        from lfring.optics.device import load_device

        device = load_device(device)
    if not isinstance(frames_by_depth, dict) or len(frames_by_depth) < 2:
        raise InvalidInputError("calibrate needs frames of the target at two or more distinct depths, as {depth_m: frame}")
    if not all(is_number(d) for d in frames_by_depth):  # "0.3" would be read as 0.3 here and nowhere else
        raise InvalidInputError(f"target depths must be positive numbers of metres, got {list(frames_by_depth)}")
    depths = [float(d) for d in frames_by_depth]
    if any(not np.isfinite(d) or d <= 0 for d in depths):
        raise InvalidInputError(f"target depths must be positive numbers of metres, got {depths}")
    rank1 = check_bool(rank1, "rank1")
    if layout is not None and not isinstance(layout, Layout):  # before any frame is read
        raise InvalidInputError(f"layout must be a lfring.views.Layout (or None: detected), got {type(layout).__name__}")
    if len(set(np.round(depths, 9))) != len(depths):
        raise InvalidInputError(f"target depths must be distinct, got {depths}")
    levels = dict(pattern=pattern, black_level=black_level, white_level=white_level)
    images = {}
    raws = []
    shape = None
    for d, f in frames_by_depth.items():
        img, name, raw = _load_frame(f, levels)
        if raw is not None:
            raws.append(raw)
        if shape is None:
            shape = img.shape[:2]
        elif img.shape[:2] != shape:
            raise InvalidInputError(
                f"all frames must have the same size: {name} is {img.shape[1]} x {img.shape[0]} px, "
                f"the first is {shape[1]} x {shape[0]} px"
            )
        _check_new_frame(img, name, float(d), images)
        images[float(d)] = (img, name)
    if device is not None:
        try:  # the optics give z0 and the checks of the depths: they must be those of these frames' camera
            device.for_frames((shape[1], shape[0]), whose="the targets' ")
        except DeviceError as exc:
            raise InvalidInputError(f"{exc}: the device is not the camera that took them (give its device file, or no "
                                    "device)") from None
    flat_img = None
    if flat is not None:
        flat_img, flat_name, _ = _load_frame(flat, levels)
        if flat_img.shape[:2] != shape:
            raise InvalidInputError(f"the flat frame {flat_name} is {flat_img.shape[1]} x {flat_img.shape[0]} px, the targets {shape[1]} x {shape[0]} px")
    if layout is None:
        img, name = (flat_img, flat_name) if flat_img is not None else images[min(images)]
        if flat_img is None:
            log.warning("no flat frame or layout given: detecting the layout on the nearest target (less precise)")
        layout = detect_layout(img, kind="flat" if flat_img is not None else "auto", rotate180=rotate180,
                               name=f"{'flat frame' if flat_img is not None else 'target frame'} {name}")
        if flat_img is not None:
            _check_flat_layout(layout, list(images.values()), rotate180)
    elif rotate180 and not layout.rotate180:
        raise InvalidInputError("rotate180 goes with a flat frame or detection: a layout records its own rotation")
    elif (layout.raw_width_px, layout.raw_height_px) != (shape[1], shape[0]):
        raise InvalidInputError(f"the layout is for {layout.raw_width_px} x {layout.raw_height_px} px frames, the targets are {shape[1]} x {shape[0]} px")
    masks = layout.masks()
    flat_views = split_views(flat_img, layout) if flat_img is not None else None
    views = {d: split_views(images[d][0], layout) for d in sorted(images)}
    if flat_views is not None:
        check_flat_views(flat_views, masks)  # the flat's faults are the flat's, not the first target's
    measured, diag = {}, []
    for d in sorted(images):
        try:
            est = estimate_plane_homographies(views[d], reference=reference, masks=masks, method=method,
                                              flat_views=flat_views)
        except LfringError as exc:  # named by the frame: which of them is over-exposed, or textureless?
            raise type(exc)(f"target frame {images[d][1]} ({d:g} m): {exc}") from None
        measured[d] = est.H_ref_from_view
        diag.append({"depth_m": d, "file": images[d][1], "alignment_residual_px": est.residual_px.tolist(),
                     "correlation": est.correlation.tolist()})
        log.info("plane %.4g m (%s): alignment residual %s px", d, images[d][1], np.round(est.residual_px, 3).tolist())
    lens = None
    dist_diag = {"estimated": False}
    if distortion:
        lens, layout, dist_diag = _lens_distortion(views, measured, layout, masks, flat_views, reference)
    if lens is not None:
        # The homographies again, between the undistorted views (the alignment residual "after").
        mx, my = undistortion_maps(lens, layout.view_shape)
        masks = layout.masks()
        flat_u = None if flat_views is None else remap_views(flat_views, mx, my)
        for i, d in enumerate(sorted(images)):
            est = estimate_plane_homographies(remap_views(views[d], mx, my), reference=reference, masks=masks,
                                              method=method, flat_views=flat_u)
            measured[d] = est.H_ref_from_view
            diag[i]["alignment_residual_before_px"] = diag[i]["alignment_residual_px"]
            diag[i]["alignment_residual_px"] = est.residual_px.tolist()
            diag[i]["correlation"] = est.correlation.tolist()
            log.info("plane %.4g m: alignment residual %s px after undoing the distortion", d,
                     np.round(est.residual_px, 3).tolist())
    z0, how = depth_origin_m, "given"
    if z0 is None and len(measured) == 2:
        if device is not None:
            z0, how = device.entrance_pupil_m, f"optics of device '{device.name}'"
        else:
            z0, how = 0.0, "assumed: no device given"
            log.warning("two planes and no device: assuming z0 = 0; give the device (or a third plane) for z0 = s")
    elif z0 is None:
        how = "fitted"
    check_disparity_sign(measured, {d: images[d][1] for d in images}, layout.view_shape)
    cal = calibration_from_plane_homographies(
        measured, reference=reference, depth_origin_m=z0, layout=layout, pattern=_common(raws, "pattern", pattern),
        rank1=rank1, provenance={"method": method, "flat": None if flat is None else str(flat), "planes": diag,
                                 "depth_origin": how, "distortion": dist_diag,
                                 **({} if device is None else {DEVICE_RECORD: device.to_dict()})},
    )
    cal = dataclasses.replace(cal, device=None if device is None else device.name, distortion=lens,
                              black_level=_common(raws, "black_level", black_level),
                              white_level=_common(raws, "white_level", white_level))
    if carry_flat:
        cal = dataclasses.replace(cal, flat_field=flat_field_from_frame(flat_img, cal))
    if how == "fitted":
        check_fitted_origin(cal.depth_origin_m, min(measured), device)
    # Without a device the built-in calibration of frames this size stands in, which may be another
    # camera's: it refuses only depths in another unit, and warns of nothing smaller.
    warn_depths_off(cal, {d: images[d][1] for d in images}, *camera_model(cal, device), warn=device is not None)
    return cal


def camera_model(cal, device=None) -> tuple:
    """A model of the camera that does not rest on the depths ``cal`` was given, and its name in
    words: ``device``'s optics at the frames' binning (:func:`calibrate` refuses a device that no
    binning fits to them), else the built-in calibration for frames of this size (what ``lfring
    inspect`` uses without a calibration); (None, '') without either."""
    from lfring.calibration.defaults import default_calibration

    if device is not None:
        return RingCalibration.from_optics(device.for_frames(cal.raw_size)), f"the optics of device '{device.name}'"
    try:
        ref, name = default_calibration(cal.raw_size)
    except LfringError:
        return None, ""
    return ref, f"the built-in calibration '{name}'"


def warn_depths_off(cal, names: dict, ref, what: str, warn: bool = True) -> None:
    """Warn (log) of consecutive planes between which the views move otherwise than the camera
    model ``ref`` (in words ``what``, :func:`camera_model`) says they move between the depths
    given, by more than :data:`DEPTH_LABEL_TOL`; ``names`` the planes' frames by depth. Two
    planes fit exactly whatever their depths, so only the optics can tell a depth measured from
    the wrong point, given for another frame or in millimetres. The motion between two planes
    does not depend on where the views were cut (their layout). More than :data:`UNIT_RATIO`
    times off is refused (:class:`InvalidInputError`): depths in another unit; less is logged
    with ``warn``."""
    from lfring.calibration.model import view_motion_px

    if ref is None:
        return
    off = []
    unit = False
    zs = sorted(names)
    for za, zb in zip(zs, zs[1:]):
        seen = view_motion_px(cal, [za, zb], cal.layout.view_shape)
        said = view_motion_px(ref, [za, zb], ref.layout.view_shape)
        if said > 0 and abs(seen / said - 1.0) > DEPTH_LABEL_TOL:
            off.append(f"between the planes given as {za:g} m and {zb:g} m ({names[za]}, {names[zb]}) the views move "
                       f"{seen:.1f} px, where those depths move them {said:.2g} px")
            unit = unit or not 1.0 / UNIT_RATIO < seen / said < UNIT_RATIO
    if unit:
        raise InvalidInputError(f"by {what}, {'; '.join(off)}: more than {UNIT_RATIO:g} times off, as depths in another "
                                f"unit are; depths are in metres from the main lens, not mm{cal.millimetres_hint(*zs)}")
    if off and warn:
        log.warning("by %s, %s: check that each depth is in metres, measured from the main lens and given in the order "
                    "of the frames (the calibration takes the depths as given)", what, "; ".join(off))


def _disc_centres(layout) -> np.ndarray:
    """(V, 2) absolute centres of the layout's discs in the (rotation-undone) raw frame."""
    return np.array([(x + c[0], y + c[1]) for (x, y, _, _), c in zip(layout.rects, layout.circles)])


def _check_flat_layout(layout, targets: list, rotate180: bool) -> None:
    """Warn when the ``targets`` ((image, name) each) show the views' discs, on average, elsewhere
    than the flat frame's ``layout`` does: a flat of another setup cuts every view off its disc."""
    found = []
    for image, name in targets:
        try:
            seen = detect_layout(image, kind="scene", rotate180=rotate180, name=f"target frame {name}")
        except LfringError:  # no discs found on the target: its own checks say more
            continue
        if seen.num_views == layout.num_views and seen.circles is not None and layout.circles is not None:
            found.append((_disc_centres(seen), name))
    if not found:
        return
    off = np.hypot(*(np.mean([c for c, _ in found], axis=0) - _disc_centres(layout)).T)
    if off.max() > FLAT_LAYOUT_TOL_PX:
        k = int(np.argmax(off))
        log.warning("the flat frame shows view %d's disc %.1f px from where the targets (%s) show it (at most %g px "
                    "expected): a flat of another setup (did the ring or the zoom move between them?); the views are "
                    "cut where the flat shows them", k, off[k], ", ".join(n for _, n in found), FLAT_LAYOUT_TOL_PX)


def check_fitted_origin(z0: float, nearest_m: float, device) -> None:
    """Refuse a z0 fitted to planes that the ring cannot have, negative (its viewpoints lie in
    front of the main lens: z0 = s > 0), and warn (log) of one that ``device`` (a
    :class:`lfring.optics.RingDevice`, or None) puts farther from its entrance pupil than
    :data:`DEPTH_ORIGIN_TOL` times ``nearest_m``, the nearest plane's depth. Either way the
    planes fit the model whatever their depths: a plane's depth is likely wrong."""
    if z0 < 0.0:
        raise InvalidInputError(
            f"z0 fitted to the planes is {z0:.4f} m, negative, where the ring cannot have it (its viewpoints lie in front "
            "of the main lens: z0 = s > 0): a plane's depth is likely wrong (each measured from the main lens, in the "
            "order of the frames?); check the depths, or give depth_origin_m (on the command line --depth-origin M, or "
            "--depth-origin optics with --device)")
    why = None
    if device is not None and abs(z0 - device.entrance_pupil_m) > DEPTH_ORIGIN_TOL * nearest_m:
        why = f"{abs(z0 - device.entrance_pupil_m) * 1e3:.0f} mm from where the optics of device '{device.name}' put it " \
              f"({device.entrance_pupil_m:.4f} m)"
    if why:
        log.warning("z0 fitted to the planes is %.4f m, %s: a plane's depth is likely wrong (each measured from the "
                    "main lens, in the order of the frames?), or the device is not this camera's; the planes fit the "
                    "model whatever their depths, so its depths would be off", z0, why)


def _lens_distortion(views, measured, layout, masks, flat_views, reference):
    """Each view's distortion fitted to the planes, or None when it does not matter (see
    :func:`calibrate`); the layout (its circles those of the undistorted views when kept) and
    the diagnostics for the provenance."""
    from lfring.calibration.distortion import KEEP_RATIO, NEGLIGIBLE_DISTORTION_PX, estimate_distortion, undistorted_circles

    if layout.circles is None:
        log.warning("the layout has no valid discs: the lens distortion is not estimated")
        return None, layout, {"estimated": False, "reason": "the layout has no valid discs"}
    try:
        fit = estimate_distortion(views, measured, reference=reference, masks=masks, circles=layout.circles,
                                  flat_views=flat_views)
    except EstimationError as exc:
        # The homographies were measured; only the finer model could not be: say so, go on without it.
        log.warning("the lens distortion could not be estimated (%s); the views are used as they are cut", exc)
        return None, layout, {"estimated": False, "reason": str(exc)}
    kept = not fit.negligible and fit.rms_px < KEEP_RATIO * fit.rms_before_px
    info = {"estimated": True, "modelled": kept, "effect_px": fit.effect_px, "tiles_rms_before_px": fit.rms_before_px,
            "tiles_rms_after_px": fit.rms_px, "tiles": fit.correspondences, "rounds": fit.rounds,
            "negligible_px": NEGLIGIBLE_DISTORTION_PX}
    log.info("lens distortion: changes the views' maps by up to %.3f px beyond a homography; tiles misregistered by "
             "%.3f px RMS with homographies alone, %.3f px with the distortion: %s", fit.effect_px, fit.rms_before_px,
             fit.rms_px, "modelled" if kept else "not modelled (negligible)")
    if not kept:
        return None, layout, info
    layout = dataclasses.replace(layout, circles=undistorted_circles(layout.circles, fit.distortion))
    return fit.distortion, layout, info


def check_disparity_sign(h_by_depth: dict, names: dict, view_shape_hw) -> None:
    """Refuse planes whose views lie farther apart than those of a nearer plane.

    The ring's physics fixes the sign of the model: views of nearer planes lie farther apart
    (the disparity d(Z) falls as Z grows). Measured homographies that say otherwise come from
    depths given in the wrong order (or frames given in the wrong order).

    Parameters
    ----------
    h_by_depth : {depth_m: (V, 3, 3)}
        Measured ``H_ref_from_view`` of each plane.
    names : {depth_m: str}
        The frame of each plane, for the message.
    view_shape_hw : (h, w)

    Raises
    ------
    InvalidInputError
        Naming the two planes whose order contradicts the physics.
    """
    from lfring.calibration.overlap import disparity_spread_px

    zs = sorted(h_by_depth)
    spread = {z: disparity_spread_px(h_by_depth[z], view_shape_hw) for z in zs}
    for near, far in zip(zs, zs[1:]):
        if spread[near] <= spread[far]:
            raise InvalidInputError(
                f"the views of the plane given as {near:g} m ({names.get(near, '?')}) lie {spread[near]:.1f} px apart, "
                f"closer than those of the plane given as {far:g} m ({names.get(far, '?')}, {spread[far]:.1f} px); "
                "views of nearer planes lie farther apart, so these depths look swapped: give each frame's depth "
                "in the order of the frames"
            )


def _check_new_frame(img: np.ndarray, name: str, depth_m: float, images: dict) -> None:
    """Refuse a frame whose pixels equal those of a frame already given for another depth.

    One photograph cannot show the target at two depths: the same file given twice (or a copy
    of it) would otherwise reach the fit and be refused there as swapped depths, a misleading
    reason.
    """
    for other_m, (other, other_name) in images.items():
        if other.shape == img.shape and np.array_equal(other, img):
            near, far = sorted((other_m, depth_m))
            files = other_name if other_name == name else f"{other_name} and {name}"
            raise InvalidInputError(
                f"the same frame is given for {near} m and {far} m ({files}): give a frame of the target "
                "at each depth"
            )


def _load_frame(frame, levels: dict):
    """(float image, name, RawFrame or None) of a frame given as a path, a RawFrame or an array."""
    from lfring.io.raw import RawFrame, load_raw

    if isinstance(frame, (str, Path)):
        frame = load_raw(frame, **levels)
    if isinstance(frame, RawFrame):
        img, name = load_image(frame)
        return img, name, frame
    img, name = load_image(frame)
    return img, name, None


def _common(raws, attr: str, given):
    """The value every frame shares (None when they differ or none is a raw frame)."""
    if given is not None:
        return given
    values = {repr(getattr(r, attr)) for r in raws}
    return getattr(raws[0], attr) if len(values) == 1 else None
