"""Building a RingCalibration: from the device's optics, from plane homographies measured
elsewhere, or from the geometry of a regular grid of views.

:func:`lfring.calibrate` (photographs of a target at known depths) builds on
:func:`calibration_from_plane_homographies`. The methods ``RingCalibration.from_optics``,
``from_plane_homographies`` and ``from_grid`` delegate here.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lfring.calibration.model import VariableHomography, fit_variable_homography
from lfring.calibration.ring import DEVICE_RECORD, RingCalibration
from lfring.core.validate import check_number
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice, load_device
from lfring.optics.views import ideal_discs_px, lens_distortions, optical_homography_model, optical_layout, view_cameras
from lfring.views import Layout, grid_layout

__all__ = ["calibration_from_grid", "calibration_from_optics", "calibration_from_plane_homographies", "check_grid_disparity"]

GRID_DISPARITY_NAMES = ("disparity_scale_px_m", "disparity_offset_px", "depth_origin_m")
"""How :func:`check_grid_disparity`'s messages name the grid's disparity model by default: the
parameters of :func:`calibration_from_grid`."""


def calibration_from_optics(device: RingDevice | str, *, layout: Layout | None = None, rotate180: bool = False) -> RingCalibration:
    """The calibration the paraxial model of ``device`` predicts (pure translations, z0 = s):
    the default when no measured calibration is given.

    Parameters
    ----------
    device : RingDevice, str or path
        The device description, or what :func:`lfring.optics.load_device` takes (a built-in
        name, a device file).
    layout : Layout, optional
        Where the views lie on the raw frame; by default the one the optics predict.
    rotate180 : bool
        Whether the predicted layout reads the raw frame rotated by 180 degrees (ignored when
        ``layout`` is given).

    Returns
    -------
    RingCalibration
        ``source='optics'``, valid from twice the entrance-pupil distance to infinity, with
        the device's distances in ``provenance``; for a device whose mini-lenses distort
        (``device.lenses``), their distortions, exactly, and the layout's circles the
        undistorted views' discs.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> cal = calibration_from_optics(load_device("prototype").binned(2))
    >>> cal.source, cal.num_views, cal.raw_size
    ('optics', 4, (2456, 1842))
    """
    device = load_device(device)
    layout = layout or optical_layout(device, rotate180=rotate180)
    a, b, z0 = optical_homography_model(device, layout, reference=0)
    s = view_cameras(device).depth_origin_m
    distortion = lens_distortions(device, layout)
    if distortion is not None:
        circles = tuple((cx - x, cy - y, r) for (cx, cy, r), (x, y, _, _) in zip(ideal_discs_px(device), layout.rects))
        layout = dataclasses.replace(layout, circles=circles)
    return RingCalibration(
        model=VariableHomography(a, b, z0, 0),
        layout=layout,
        distortion=distortion,
        valid_depth_range_m=(round(2 * s, 6), None),
        source="optics",
        device=device.name,
        provenance={"ring_distance_m": device.ring_distance_m, "sensor_distance_m": device.sensor_distance_m,
                    "pixel_pitch_m": device.pixel_pitch_m, DEVICE_RECORD: device.to_dict()},
    )


def calibration_from_plane_homographies(
    homographies_by_depth: dict,
    *,
    reference: int = 0,
    depth_origin_m: float | None = 0.0,
    layout: Layout,
    pattern: str | None = None,
    rank1: bool = False,
    provenance: dict | None = None,
) -> RingCalibration:
    """Fit the model to homographies from elsewhere: ``{depth_m: H (V, 3, 3)}`` where each H
    maps a view's pixels into view ``reference``; ``depth_origin_m=None`` fits z0 (three
    or more planes).

    Parameters
    ----------
    homographies_by_depth : dict of float to (V, 3, 3) array_like
        ``H_ref_from_view`` of every view for a plane at each depth in metres (two or more).
    reference : int
        The view the homographies map into.
    depth_origin_m : float or None
        z0 of the model; None fits it (three or more planes).
    layout : Layout
        The layout the homographies were measured with.
    pattern : str or None
        Bayer pattern of the frames, when known.
    rank1 : bool
        Fit every ``B_k`` as a rank-1 matrix (the ring's are pure translations).
    provenance : dict, optional
        Where the homographies came from, kept in the calibration.

    Returns
    -------
    RingCalibration
        ``source='planes'``, valid between the nearest and farthest plane, with each plane's
        residuals in ``planes``.

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.views import grid_layout
    >>> def shift(x_px):
    ...     h = np.repeat(np.eye(3)[None], 2, axis=0)
    ...     h[1, 0, 2] = x_px
    ...     return h
    >>> cal = calibration_from_plane_homographies({1.0: shift(10.0), 2.0: shift(5.0)},
    ...                                           layout=grid_layout((8, 8), [(0, 0), (1, 0)]))
    >>> cal.valid_depth_range_m, round(float(cal.homography(1, 1.25, reference=0)[0, 2]), 6)
    ((1.0, 2.0), 8.0)
    """
    if not isinstance(layout, Layout):
        raise InvalidInputError("from_plane_homographies needs the layout the homographies were measured with")
    model, planes = fit_variable_homography(
        homographies_by_depth, shape_hw=layout.view_shape, reference=reference, depth_origin_m=depth_origin_m, rank1=rank1
    )
    depths = [p.depth_m for p in planes]
    return RingCalibration(
        model=model, layout=layout, valid_depth_range_m=(min(depths), max(depths)), pattern=pattern,
        planes=tuple(planes), source="planes", provenance=dict(provenance or {}),
    )


def calibration_from_grid(
    view_shape: tuple[int, int],
    grid_positions,
    *,
    disparity_scale_px_m: float,
    disparity_offset_px: float = 0.0,
    depth_origin_m: float = 0.0,
    valid_depth_range_m: tuple[float, float | None] | None = None,
) -> RingCalibration:
    """The calibration of views on a regular grid, built from its geometry: a rectified
    stereo pair, a camera array, the sub-aperture views of a light-field camera.

    Parameters
    ----------
    view_shape : (h, w)
        Size of every view in pixels.
    grid_positions : (V, 2) array_like
        (x, y) of each view on the grid in grid units, x to the right, y down, in view
        order; 2 to ``MAX_VIEWS`` distinct positions. A rectified stereo pair is
        ``[(0, 0), (1, 0)]``, left view first.
    disparity_scale_px_m, disparity_offset_px : float
        The disparity per grid step of a point at depth Z, an affine function of
        1 / (Z - z0): ``d(Z) = disparity_offset_px + disparity_scale_px_m / (Z - z0)``
        pixels (for a stereo pair of focal length f px and baseline b m, ``f b`` and 0).
    depth_origin_m : float
        z0, the depth of the plane of the projection centres (0 for cameras whose depth
        is measured from their centres).
    valid_depth_range_m : (float, float or None), optional
        Depths the calibration is meant for (others warn). By default from the depth at
        which ``disparity_scale_px_m / (Z - z0)`` is one view's larger side (nearer than
        that, neighbouring views no longer overlap) to infinity.

    Returns
    -------
    RingCalibration
        ``source='grid'``; the layout tiles the views as cells of a mosaic (at their grid
        cell for integer positions, else in one row in view order) and the grid is kept
        in ``provenance``.

    Notes
    -----
    A point at depth Z lies at ``x_k = x_j - (p_k - p_j) d(Z)`` in view k for its position
    ``x_j`` in view j (both axes; p the grid positions), so
    ``H_ref_from_view_k(Z)`` is the translation by ``(p_k - p_ref) d(Z)``, with
    ``p_ref`` the mean of the positions for reference 'center'. For a Middlebury pair
    (left, right) at ``[(0, 0), (1, 0)]`` this is ``imL(x, y) = imR(x - d, y)``.

    Examples
    --------
    >>> cal = calibration_from_grid((375, 450), [(0, 0), (1, 0)], disparity_scale_px_m=100.0)
    >>> cal.homographies(2.0)[:, 0, 2]  # 50 px of disparity, half of it each way from the centre
    array([-25.,  25.])
    """
    pos = np.asarray(grid_positions, dtype=np.float64) if _is_numeric(grid_positions) else None
    if pos is None or pos.ndim != 2 or pos.shape[1] != 2 or not np.all(np.isfinite(pos)):
        got = f"shape {pos.shape}" if pos is not None else repr(grid_positions)[:80]
        raise InvalidInputError(
            f"grid_positions must be (V, 2) finite (x, y) grid positions, got {got}; a stereo pair is [(0, 0), (1, 0)]"
        )
    layout = grid_layout(view_shape, pos)
    scale, offset, z0 = check_grid_disparity(disparity_scale_px_m, disparity_offset_px, depth_origin_m)
    if valid_depth_range_m is None:
        valid_depth_range_m = (z0 + abs(scale) / max(layout.view_shape), None)
    rel = pos - pos[0]
    a = np.repeat(np.eye(3)[None], len(pos), axis=0)
    b = np.zeros_like(a)
    a[:, :2, 2] = rel * offset
    b[:, :2, 2] = rel * scale
    return RingCalibration(
        model=VariableHomography(a, b, z0, 0),
        layout=layout,
        valid_depth_range_m=valid_depth_range_m,
        source="grid",
        provenance={"grid_positions": pos.tolist(), "disparity_scale_px_m": scale, "disparity_offset_px": offset,
                    "disparity": "d(Z) = disparity_offset_px + disparity_scale_px_m / (Z - depth_origin_m) px per "
                                 "grid step; view k at grid position p_k: H_ref_from_view = translation by (p_k - p_ref) d(Z)"},
    )


def check_grid_disparity(disparity_scale_px_m, disparity_offset_px, depth_origin_m, *,
                         names: tuple[str, str, str] = GRID_DISPARITY_NAMES) -> tuple[float, float, float]:
    """The disparity model of a grid of views, checked: each number finite, the scale not 0.

    A scale of 0 would make the views' disparity the same at every depth: the calibration could
    not tell one depth from another.

    Parameters
    ----------
    disparity_scale_px_m, disparity_offset_px, depth_origin_m : float
        As :func:`calibration_from_grid` takes them.
    names : (str, str, str)
        How the messages name the three numbers (the command line passes its options).

    Returns
    -------
    (scale, offset, z0) : floats

    Raises
    ------
    InvalidInputError
        Naming the number at fault.

    Examples
    --------
    >>> from lfring.calibration.build import check_grid_disparity
    >>> check_grid_disparity(100, 0, 0)
    (100.0, 0.0, 0.0)
    >>> check_grid_disparity(0.0, 0, 0, names=("--disparity-scale", "--disparity-offset", "--depth-origin"))
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: --disparity-scale must not be 0: the views would not move with depth
    """
    scale_name, offset_name, origin_name = names
    scale = check_number(disparity_scale_px_m, scale_name)
    offset = check_number(disparity_offset_px, offset_name)
    z0 = check_number(depth_origin_m, origin_name)
    if scale == 0:
        raise InvalidInputError(f"{scale_name} must not be 0: the views would not move with depth")
    return scale, offset, z0


def _is_numeric(value) -> bool:
    """Whether ``value`` reads as an array of integers or floats (not strings, not objects)."""
    try:
        return np.asarray(value).dtype.kind in "iuf"
    except (TypeError, ValueError):
        return False
