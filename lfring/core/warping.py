"""Warping views into the reference frame, and the one test of whether a homography is a
translation (:func:`translation_of`), which decides whether the cheaper shift engine
(:mod:`lfring.core.shift`) can do the same work.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.viewstack import check_views
from lfring.errors import InvalidInputError

__all__ = ["DEFAULT_INTERPOLATION", "INTERPOLATIONS", "TRANSLATION_TOL_PX", "interpolation_flag", "translation_of",
           "translations", "warp_image", "warp_views"]

INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
# The one default of the library, the CLI and batches: bilinear takes the shift engine (and the
# torch backend has it); bicubic keeps a little more detail at several times the cost.
DEFAULT_INTERPOLATION = "linear"
# A homography is treated as a translation when it is one to within this many pixels over the
# whole reference frame (translation_of proves the bound); refocusing and depth both ask this.
TRANSLATION_TOL_PX = 1e-3


def interpolation_flag(name: str) -> int:
    """The OpenCV flag of an interpolation name ('linear' or 'cubic')."""
    if name not in INTERPOLATIONS:
        raise InvalidInputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {name!r}")
    return INTERPOLATIONS[name]


def warp_image(src: np.ndarray, H: np.ndarray, size_wh, dst=None, *, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Warp one image by ``H`` (view -> reference) into a frame of ``size_wh`` (width, height),
    zero outside; affine maps take ``cv2.warpAffine``, the others ``cv2.warpPerspective``."""
    if abs(H[2, 0]) < 1e-12 and abs(H[2, 1]) < 1e-12:
        return cv2.warpAffine(src, H[:2].astype(np.float64), size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)
    return cv2.warpPerspective(src, H, size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)


def warp_views(views, H_ref_from_view, *, masks=None, out_shape=None, interpolation: str = DEFAULT_INTERPOLATION):
    """Warp every view into the reference frame.

    Parameters
    ----------
    views : (V, h, w, C) float32
    H_ref_from_view : (V, 3, 3)
    masks : (V, h, w) float32, optional
        Valid weight of every view pixel (see :func:`view_masks`); ones when None.
    out_shape : (h, w), optional
        Size of the reference frame (the views' size by default).
    interpolation : {'linear', 'cubic'}

    Returns
    -------
    warped : (V, H, W, C) float32
        Each view warped and multiplied by its warped mask (zero where it is not valid).
    weights : (V, H, W) float32
        The warped masks.

    Examples
    --------
    >>> import numpy as np
    >>> views = np.ones((2, 4, 5, 1), np.float32)
    >>> H = np.stack([np.eye(3), [[1, 0, 1], [0, 1, 0], [0, 0, 1]]])  # the second moves 1 px right
    >>> warped, weights = warp_views(views, H)
    >>> weights[1, 0].tolist()
    [0.0, 1.0, 1.0, 1.0, 1.0]
    """
    arr = check_views(views, images=False)
    hs = np.asarray(H_ref_from_view, dtype=np.float64)
    if hs.shape != (arr.shape[0], 3, 3):
        raise InvalidInputError(f"need one 3 x 3 homography per view, got {hs.shape} for {arr.shape[0]} views")
    flag = interpolation_flag(interpolation)
    oh, ow = out_shape or arr.shape[1:3]
    warped = np.empty((arr.shape[0], oh, ow, arr.shape[3]), np.float32)
    weights = np.empty((arr.shape[0], oh, ow), np.float32)
    for k in range(arr.shape[0]):
        m = np.ones(arr.shape[1:3], np.float32) if masks is None else masks[k]
        warp_image(m, hs[k], (ow, oh), dst=weights[k])
        src = arr[k] if masks is None else arr[k] * m[..., None]
        out = warp_image(src, hs[k], (ow, oh), dst=warped[k], interpolation=flag)
        if out.ndim == 2:
            warped[k, ..., 0] = out
    return warped, weights


def translation_of(H: np.ndarray, out_shape, *, tol_px: float = TRANSLATION_TOL_PX):
    """The shift ``s`` (x, y) such that reference pixel ``x`` samples view pixel ``x + s`` to
    within ``tol_px`` everywhere in the reference frame of ``out_shape`` (h, w), or None.

    This is the one test of "is this homography a translation" that refocusing and depth share.

    Notes
    -----
    ``G = H^-1`` maps reference pixels to view pixels. With ``q(x) = g.x + 1`` its denominator
    (positive over the frame, else None), ``G(x) - x - s = (L(x) - x (g.x)) / q(x)`` where ``L``
    is affine, so ``|G(x) - x - s| <= (max|L| + max|x| max|g.x|) / min q`` with every maximum
    and minimum taken at the frame's corners: a rigorous bound, not a sample.

    Examples
    --------
    >>> import numpy as np
    >>> translation_of(np.array([[1.0, 0, 2.5], [0, 1, -1], [0, 0, 1]]), (10, 20)).tolist()
    [-2.5, 1.0]
    >>> translation_of(np.array([[1.01, 0, 2.5], [0, 1, -1], [0, 0, 1]]), (10, 20)) is None
    True
    """
    s = translations(np.asarray(H, dtype=np.float64)[None], out_shape, tol_px=tol_px)
    return None if s is None else s[0]


def translations(hs, out_shape, *, tol_px: float = TRANSLATION_TOL_PX):
    """(..., 2) sampling shifts of a stack of homographies (..., 3, 3), each as
    :func:`translation_of` defines it (the bound of its Notes, vectorised over the stack), or
    None when any of them is not a translation."""
    hs = np.asarray(hs, dtype=np.float64)
    lead = hs.shape[:-2]
    try:
        g = np.linalg.inv(hs.reshape(-1, 3, 3))
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(g)) or np.any(g[:, 2, 2] == 0):
        return None
    g = g / g[:, 2:3, 2:3]
    rows, cols = out_shape
    corners = np.array([[0, 0], [cols - 1, 0], [0, rows - 1], [cols - 1, rows - 1]], dtype=np.float64)
    gx = corners @ g[:, 2, :2].T  # (4, M)
    q = gx + 1.0
    if q.min() <= 0:
        return None
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2])
    s = (g[:, :2, :2] @ centre + g[:, :2, 2]) / (g[:, 2, :2] @ centre + 1.0)[:, None] - centre  # (M, 2)
    lin_mat = g[:, :2, :2] - np.eye(2) - s[:, :, None] * g[:, None, 2, :2]  # (M, 2, 2)
    lin = np.einsum("cj,mij->mci", corners, lin_mat) + (g[:, :2, 2] - s)[:, None, :]  # (M, 4, 2)
    bound = (np.abs(lin).max(axis=1) + corners.max(axis=0) * np.abs(gx).max(axis=0)[:, None]) / q.min(axis=0)[:, None]
    if bound.max() > tol_px:
        return None
    return s.reshape(*lead, 2)
