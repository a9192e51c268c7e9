"""The variable-homography model H_k(Z) = A_k + B_k / (Z - z0) of the source paper, and its fit.

For a plane at distance Z the homography that maps view k onto the reference view is affine in
1 / (Z - z0) when the views' projection centres lie in one plane parallel to the target, at
depth z0 (for the ring, the entrance pupil s = b FL / (b - FL)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfring.core.validate import check_view_index, is_number
from lfring.errors import EstimationError, InvalidInputError
from lfring.core.geometry import apply_homography, homography_rms_px, normalize_homographies

__all__ = ["MAX_CONDITION", "VariableHomography", "PlaneFit", "check_depth_origin", "fit_variable_homography", "view_motion_px"]


@dataclass(frozen=True, eq=False)
class PlaneFit:
    """Diagnostics of one plane: the model's RMS error against its measured homographies (px,
    per view) and, with three or more planes, the error predicting it from the other planes
    (None with exactly three and z0 fitted: the others cannot fit z0 without it)."""

    depth_m: float
    residual_px: np.ndarray
    leave_one_out_px: np.ndarray | None


MAX_CONDITION = 1e12
"""A view's A (its map at infinite depth) with a condition number from this one is singular."""


@dataclass(frozen=True, eq=False)
class VariableHomography:
    """``H_r_from_k(Z) = A[k] + B[k] / (Z - depth_origin_m)`` into reference view r, normalised
    so that H[2, 2] = 1 (B[k][2, 2] is 0)."""

    A: np.ndarray
    B: np.ndarray
    depth_origin_m: float
    reference: int

    def __post_init__(self) -> None:
        a, b = np.asarray(self.A, dtype=np.float64), np.asarray(self.B, dtype=np.float64)
        if a.ndim != 3 or a.shape[1:] != (3, 3) or a.shape != b.shape:
            raise InvalidInputError(f"A and B must both be (V, 3, 3), got {a.shape} and {b.shape}")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.isfinite(self.depth_origin_m)):
            raise InvalidInputError("A, B and depth_origin_m must be finite")
        singular = [k for k in range(len(a)) if not np.linalg.cond(a[k]) < MAX_CONDITION]
        if singular:  # H at infinity: a homography must map the plane onto the plane
            raise InvalidInputError(f"A of view {singular[0]} is singular (condition number "
                                    f"{np.linalg.cond(a[singular[0]]):.3g}): it is no homography")
        # Own read-only copies: what is derived from a calibration is cached while it lives, so an
        # edit in place would leave those caches stale (make a new calibration instead).
        a, b = a.copy(), b.copy()
        a.setflags(write=False)
        b.setflags(write=False)
        object.__setattr__(self, "A", a)
        object.__setattr__(self, "B", b)

    @property
    def num_views(self) -> int:
        """Number of views V (the first axis of ``A`` and ``B``)."""
        return self.A.shape[0]

    def __call__(self, depth_m) -> np.ndarray:
        """(V, 3, 3), or (N, V, 3, 3) for N depths: H_r_from_k at ``depth_m``."""
        z = np.asarray(depth_m, dtype=np.float64)
        if not np.all(np.isfinite(z)) or np.any(z <= self.depth_origin_m):
            raise InvalidInputError(
                f"depth must be finite and beyond the depth origin {self.depth_origin_m:.4g} m, got {depth_m!r}"
            )
        inv = (1.0 / (z - self.depth_origin_m))[..., None, None, None]
        return normalize_homographies(self.A + self.B * inv)


def _solve(hs: np.ndarray, z: np.ndarray, z0: float, rank1: bool) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of H = A + B x with x = 1/(Z - z0), element by element (exact for 2 planes)."""
    x = 1.0 / (z - z0)
    design = np.stack([np.ones_like(x), x], axis=1)  # (N, 2)
    flat = hs.reshape(len(z), -1)
    coef = np.linalg.pinv(design) @ flat  # (2, V*9)
    a = coef[0].reshape(hs.shape[1:])
    b = coef[1].reshape(hs.shape[1:])
    if rank1:
        # Best rank-1 B_k (the ring's B_k is a pure translation, t e3^T), then A given B.
        for k in range(b.shape[0]):
            u, s, vt = np.linalg.svd(b[k])
            b[k] = s[0] * np.outer(u[:, 0], vt[0])
        a = (hs - b[None] * x[:, None, None, None]).mean(axis=0)
    return a, b


def _errors(hs, z, a, b, z0, shape_hw) -> np.ndarray:
    pred = normalize_homographies(a[None] + b[None] / (z - z0)[:, None, None, None])
    return homography_rms_px(pred, hs, shape_hw, step=8)


def check_depth_origin(depth_origin_m, nearest_m: float, *, name: str = "depth_origin_m") -> float:
    """``depth_origin_m`` as a float, if the model can use it with planes from ``nearest_m`` on.

    The model divides by Z - z0, so z0 must be finite and in front of every plane; a z0 at or
    beyond the nearest plane puts a pole of the model among the planes.

    Parameters
    ----------
    depth_origin_m : float
        z0 in metres.
    nearest_m : float
        The nearest plane's depth in metres.
    name : str
        How the message names z0 (the command line passes its option).

    Returns
    -------
    float

    Raises
    ------
    InvalidInputError
        When z0 is not finite or not nearer than the nearest plane.

    Examples
    --------
    >>> from lfring.calibration.model import check_depth_origin
    >>> check_depth_origin(0.028, 0.3)
    0.028
    >>> check_depth_origin(0.5, 0.3, name="--depth-origin")
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: --depth-origin (0.5) must be finite and in front of the nearest plane (0.3 m)
    """
    z0 = float(depth_origin_m) if is_number(depth_origin_m) else float("nan")
    if not np.isfinite(z0) or z0 >= nearest_m:
        raise InvalidInputError(
            f"{name} ({depth_origin_m}) must be finite and in front of the nearest plane ({nearest_m:g} m)")
    return z0


def fit_variable_homography(
    homographies_by_depth: dict,
    *,
    shape_hw: tuple[int, int],
    reference: int = 0,
    depth_origin_m: float | None = 0.0,
    rank1: bool = False,
) -> tuple[VariableHomography, list[PlaneFit]]:
    """Fit A_k, B_k (and z0) to homographies measured on planes at known depths.

    Parameters
    ----------
    homographies_by_depth : {depth_m: (V, 3, 3)}
        H_r_from_k of each plane, into reference view ``reference``.
    shape_hw : (h, w)
        View size; residuals are RMS pixel distances over this grid.
    depth_origin_m : float or None
        z0. None fits it (three or more planes needed).
    rank1 : bool
        Constrain every B_k to rank 1 (true of camera centres on a plane parallel to the target).

    Returns
    -------
    model : VariableHomography
    planes : list of PlaneFit, in order of depth

    Notes
    -----
    With z0 fixed the model is linear in A and B: two planes determine it exactly, more give
    least squares. z0 is fitted by a bounded 1-D search minimising the RMS pixel residual.
    """
    if not isinstance(homographies_by_depth, dict) or len(homographies_by_depth) < 2:
        n = len(homographies_by_depth) if isinstance(homographies_by_depth, dict) else 0
        raise InvalidInputError(f"the variable-homography model needs planes at two or more depths, got {n}")
    depths = np.array([float(d) for d in homographies_by_depth], dtype=np.float64)
    if not np.all(np.isfinite(depths)) or np.any(depths <= 0):
        raise InvalidInputError(f"plane depths must be positive numbers of metres, got {sorted(homographies_by_depth)}")
    order = np.argsort(depths)
    depths = depths[order]
    if np.any(np.diff(depths) <= 1e-6):
        raise InvalidInputError(f"plane depths must be distinct, got {depths.tolist()}")
    keys = list(homographies_by_depth)
    hs = np.stack([np.asarray(homographies_by_depth[keys[i]], dtype=np.float64) for i in order])
    if hs.ndim != 4 or hs.shape[2:] != (3, 3) or not np.all(np.isfinite(hs)):
        raise InvalidInputError(f"each plane needs finite (V, 3, 3) homographies, got shape {hs.shape[1:]}")
    hs = normalize_homographies(hs)
    reference = check_view_index(reference, "reference", hs.shape[1])

    fitted = depth_origin_m is None
    if fitted:
        if len(depths) < 3:
            raise InvalidInputError("fitting the depth origin z0 needs three or more planes; give depth_origin_m for two")
        z0 = _fit_origin(hs, depths, rank1, shape_hw)
    else:
        z0 = check_depth_origin(depth_origin_m, float(depths[0]))
    a, b = _solve(hs, depths, z0, rank1)
    model = VariableHomography(a, b, z0, int(reference))
    residual = _errors(hs, depths, a, b, z0, shape_hw)
    loo = None
    # Each plane predicted by a model of the others (with z0 as fitted to all). Three planes and
    # z0 fitted fit any three depths exactly, so no plane can check the others: None.
    if len(depths) >= 3 and not (fitted and len(depths) == 3):
        loo = np.zeros_like(residual)
        for i in range(len(depths)):
            keep = np.arange(len(depths)) != i
            ai, bi = _solve(hs[keep], depths[keep], z0, rank1)
            loo[i] = _errors(hs[i : i + 1], depths[i : i + 1], ai, bi, z0, shape_hw)[0]
    planes = [PlaneFit(float(d), residual[i], None if loo is None else loo[i]) for i, d in enumerate(depths)]
    if not np.all(np.isfinite(residual)):
        raise EstimationError("the variable-homography fit produced non-finite residuals")
    return model, planes


def _fit_origin(hs, depths, rank1: bool, shape_hw) -> float:
    """The z0 that minimises the RMS pixel residual of the planes ``hs`` at ``depths``: a grid over
    the depths before the nearest plane, then a bounded 1-D search around its best."""

    def cost(z0):
        a, b = _solve(hs, depths, z0, rank1)
        return float(np.sqrt(np.mean(_errors(hs, depths, a, b, z0, shape_hw) ** 2)))

    hi = depths[0] - 1e-3
    lo = hi - max(1.0, 4 * (depths[-1] - depths[0]))
    grid = np.linspace(lo, hi, 41)
    costs = [cost(g) for g in grid]
    i = int(np.argmin(costs))
    from scipy.optimize import minimize_scalar  # here, not at import: it is much of every command's start-up

    res = minimize_scalar(cost, bounds=(grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]), method="bounded",
                          options={"xatol": 1e-7})
    return float(res.x)


def view_motion_px(calibration, depths_m, view_shape) -> float:
    """Largest distance any view pixel moves in the reference frame between consecutive depths
    of ``depths_m`` (its corners bound it: the maps are affine, or nearly so)."""
    h, w = view_shape
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
    hs = calibration.model(np.asarray(depths_m, dtype=np.float64))
    steps = [np.abs(apply_homography(hs[i, k], corners) - apply_homography(hs[i + 1, k], corners)).max()
             for i in range(len(hs) - 1) for k in range(hs.shape[1])]
    return float(max(steps)) if steps else 0.0
