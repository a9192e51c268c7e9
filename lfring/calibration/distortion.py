"""Each view's lens distortion, estimated from the photographs of the target the calibration is
made of.

Views of one textured plane are related by homographies only through ideal mini-lenses. Through
real ones, views j and k are related by ``x_j = F_j(H(F_k^-1(x_k)))``, F the lenses'
distortions (ideal pixel -> recorded pixel), H the plane's homography between the undistorted
views. The target's texture gives that map densely: every square tile of view j is found in
view k (:func:`lfring.calibration.planes.local_shifts`, after view k is undistorted and warped
by the current homography), and each tile is a correspondence. Every view's distortion (a
:class:`lfring.core.lens.PolynomialDistortion`) and a homography per plane and pair of views are
fitted to all of them together by least squares; the views are undistorted with the result and
measured again, until the distortions stop changing.

What the data can tell apart
----------------------------
Any homography composed with a view's distortion (on its ideal side) is absorbed by that view's
homographies: only the part of a distortion that is not projective is measured, and the model
has none (no affine terms, nor the quadratic term a projective change of frame makes). A
distortion common to every view is seen only through the views' parallax (``F(x + t) - F(x)``
for the views' offset t): its quadratic part changes every view-to-view map by an affine map
that the homographies absorb exactly, and cannot be measured; its higher terms are measured,
less precisely than each view's own. The part of a view's disc that no other view overlaps is
not measured at all. A small ridge on the coefficients settles what is not measured (towards
no distortion). Whatever is common to every view, like the main lens's own distortion, bends
the refocused image a little but moves no view against another: it disturbs neither refocusing
nor depth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.calibration.planes import local_shifts
from lfring.core.geometry import apply_homography
from lfring.core.lens import (
    FLAT_FLOOR,
    POLYNOMIAL_TERMS,
    PolynomialDistortion,
    polynomial_basis,
    remap_views,
    undistortion_maps,
)
from lfring.core.records import record_repr
from lfring.errors import EstimationError

__all__ = [
    "KEEP_RATIO",
    "NEGLIGIBLE_DISTORTION_PX",
    "DistortionFit",
    "distortion_effect_px",
    "estimate_distortion",
    "undistort_masks",
    "undistorted_circles",
]

log = logging.getLogger("lfring.calibration")

NEGLIGIBLE_DISTORTION_PX = 0.02
"""A fitted distortion that changes no plane's view-to-reference map by more than this (RMS over
the view, after the best homography; :func:`distortion_effect_px`) is not kept: the views are
then used as they are, exactly as without a distortion model."""

KEEP_RATIO = 0.8
"""A fitted distortion is kept only when it brings the tiles' RMS misregistration below this
fraction of what homographies alone leave: on frames of ideal lenses the fit explains noise and
gains a few per cent at most."""

#: rounds of measure (undistort, tiles) and fit: the first measures the views as they are
#: (tiles up to a few pixels off, measured less precisely), the second on views nearly
#: undistorted; a third changes the view-to-view maps by far less than the tiles' noise.
_MAX_ROUNDS = 2
#: tiles of the correspondences: this fraction of the disc's radius on a side (about 32 px on
#: the binned twin: a few hundred tiles per view and plane).
_TILE_FRACTION = 0.09
#: fewest tiles a pair of views of one plane must share to take part.
_MIN_TILES = 16
#: the tiles kept only inside the discs shrunk by this fraction of their radius (their rims are
#: dark and, without a flat, uneven).
_RIM_FRACTION = 0.04
#: weight (pixels of residual per pixel of rim displacement) of the rows that keep every
#: coefficient small where the data says nothing.
_RIDGE_WEIGHT = 1e-2
#: most Levenberg-Marquardt steps per round, and the relative decrease of the cost below which
#: they stop (the correspondences' noise is far above what smaller steps change).
_LM_ITERATIONS = 30
_LM_TOLERANCE = 1e-3
#: scale (px) beyond which a correspondence's residual counts linearly (soft L1): a tile that
#: locked on the wrong speckle does not pull the fit.
_ROBUST_SCALE_PX = 0.05


@dataclass(frozen=True, eq=False)
class DistortionFit:
    """The distortions fitted to the target planes, with diagnostics.

    Attributes
    ----------
    distortion : tuple of PolynomialDistortion
        One per view (view pixels, ideal -> recorded), centred on the view's disc, ``scale_px``
        its radius.
    homographies : dict of float to (V, 3, 3)
        Each plane's ``H_ref_from_view`` between the undistorted views (identity for the
        reference, NaN for a view that shares too little of the plane with it).
    rms_px : float
        RMS of the correspondences' residuals after the fit, pixels.
    rms_before_px : float
        The same with homographies alone (no distortion), in the first round.
    correspondences : int
        Tiles measured, over every plane and pair of views, in the last round.
    rounds : int
    effect_px : float
        :func:`distortion_effect_px` of the fit: how much the distortions change the planes'
        view-to-reference maps beyond a homography (RMS over the view, worst plane and view).
    """

    __repr__ = record_repr

    distortion: tuple
    homographies: dict
    rms_px: float
    rms_before_px: float
    correspondences: int
    rounds: int
    effect_px: float

    @property
    def negligible(self) -> bool:
        """True when the distortion changes no plane's map by more than
        :data:`NEGLIGIBLE_DISTORTION_PX`."""
        return self.effect_px <= NEGLIGIBLE_DISTORTION_PX


def estimate_distortion(views_by_depth: dict, homographies_by_depth: dict, *, reference: int, masks, circles,
                        flat_views=None) -> DistortionFit:
    """Fit every view's distortion to the target planes, jointly with the planes' homographies.

    Parameters
    ----------
    views_by_depth : dict of float to (V, h, w, C) float32
        The views of each plane's frame, as split (not undistorted).
    homographies_by_depth : dict of float to (V, 3, 3)
        Each plane's ``H_ref_from_view`` measured on those views (the starting point).
    reference : int
        The view the homographies map into.
    masks : (V, h, w) bool
        Each view's valid disc.
    circles : sequence of (cx, cy, r)
        Each view's valid disc in view pixels: the distortions are centred there, normalised by r.
    flat_views : (V, h, w[, C]), optional
        A flat frame's views: the views are divided by it before they are compared.

    Returns
    -------
    DistortionFit

    Raises
    ------
    EstimationError
        Too few tiles could be matched (a target without texture, or views far from the
        homographies given).

    Notes
    -----
    Every pair of views (j, k) of every plane i is matched, tile by tile, after view k is
    undistorted and warped onto view j by the current homography; each tile gives recorded
    points ``x_k``, ``x_j``. The unknowns are the coefficients of every view's
    :class:`~lfring.core.lens.PolynomialDistortion` F and a homography per plane and pair;
    the residual of a tile is ``H_ijk(F_k^-1(x_k)) - F_j^-1(x_j)`` in pixels, minimised by
    Gauss-Newton (derivatives of ``F^-1`` through ``F``'s Jacobian) with Huber weights and a
    small ridge on the coefficients (it fixes what the data cannot see: a distortion common to
    every view's quadratic terms, the parts of a view no other view overlaps).
    """
    depths = sorted(homographies_by_depth)
    num = masks.shape[0]
    lum = {z: _luminance(views_by_depth[z], flat_views, masks) for z in depths}
    dist = tuple(PolynomialDistortion((float(cx), float(cy)), float(r)) for cx, cy, r in circles)
    radius = float(min(r for _, _, r in circles))
    tile = max(16, int(round(_TILE_FRACTION * radius)))
    pairs = [(j, k) for j in range(num) for k in range(j + 1, num)]
    hom = {}
    for z in depths:
        h = np.asarray(homographies_by_depth[z], np.float64)
        hom[z] = {(j, k): _normalised(np.linalg.inv(h[j]) @ h[k]) for j, k in pairs}
    rms_before = None
    rounds = 0
    for rounds in range(1, _MAX_ROUNDS + 1):
        # Pairs of views that share too little of the target to measure are left out; every
        # view must still be in some pair.
        corr = [c for c in _correspondences(lum, hom, dist, masks, circles, tile) if len(c[3]) >= _MIN_TILES]
        count = sum(len(c[3]) for c in corr)
        seen = {v for c in corr for v in c[1:3]}
        if len(seen) < num:
            raise EstimationError(
                f"too few tiles of the target could be matched between the views (tiles of {tile} px; view(s) "
                f"{sorted(set(range(num)) - seen)} in no pair with {_MIN_TILES} or more): is the target textured and "
                "in the field of every view?")
        if rms_before is None:
            # What homographies alone leave: each plane's and pair's, by linear least squares.
            rms_before = float(np.sqrt(np.mean(np.concatenate([
                np.sum((apply_homography(_solve_homography(xk, xj), xk) - xj) ** 2, axis=1) for _, _, _, xk, xj in corr]))))
        dist, hom, rms = _solve(corr, dist, hom, radius)
        log.debug("distortion round %d: %d tiles, RMS %.4f px", rounds, count, rms)
        if rms >= KEEP_RATIO * rms_before:
            break  # the distortion explains nothing the homographies leave: nothing to refine
    out_h = {}
    for z in depths:
        h = np.tile(np.eye(3), (num, 1, 1))
        for k in range(num):
            pair = (min(k, reference), max(k, reference))
            if k != reference and pair not in hom.get(z, {}):
                h[k] = np.nan  # the view shares too little with the reference on this plane
            elif k != reference:
                hk = hom[z][pair]
                h[k] = hk if pair[0] == reference else np.linalg.inv(hk)
                h[k] /= h[k][2, 2]
        out_h[z] = h
    return DistortionFit(distortion=dist, homographies=out_h, rms_px=rms, rms_before_px=rms_before,
                         correspondences=count, rounds=rounds,
                         effect_px=distortion_effect_px(dist, out_h, masks, reference))


def distortion_effect_px(distortions, homographies_by_depth: dict, masks, reference: int) -> float:
    """How much the distortions change the planes' view-to-reference maps beyond a homography:
    for each plane and view, the map ``F_r(H(F_k^-1(x)))`` over a grid of the view's disc (where
    it lands in the reference's), less the homography that fits it best; the largest RMS in
    pixels. 0 for identity distortions."""
    if all(d is None or d.is_identity for d in distortions):
        return 0.0
    worst = 0.0
    h, w = masks.shape[1:]
    for hs in homographies_by_depth.values():
        for k in range(len(distortions)):
            if k == reference or not np.all(np.isfinite(hs[k])):
                continue
            ys, xs = np.nonzero(masks[k][::8, ::8])
            pts = np.stack([xs * 8.0, ys * 8.0], axis=-1)
            mapped = distortions[reference].distort(apply_homography(hs[k], distortions[k].undistort(pts)))
            ix, iy = np.round(mapped).astype(int).T
            seen = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
            seen[seen] = masks[reference][iy[seen], ix[seen]]
            if seen.sum() < 8:
                continue
            hom = _solve_homography(pts[seen], mapped[seen])
            err = apply_homography(hom, pts[seen]) - mapped[seen]
            worst = max(worst, float(np.sqrt(np.mean(np.sum(err * err, axis=1)))))
    return worst


def undistort_masks(masks, distortions, *, maps=None) -> np.ndarray:
    """(V, h, w) bool: the ideal pixels whose recorded position lies inside the view's mask
    (``maps``: the distortions' :func:`~lfring.core.lens.undistortion_maps`, when made already)."""
    mx, my = undistortion_maps(distortions, masks.shape[1:]) if maps is None else maps
    out = remap_views(masks.astype(np.float32)[..., None], mx, my)[..., 0]
    return out > 0.999


def undistorted_circles(circles, distortions) -> tuple:
    """Each view's valid disc (cx, cy, r) in the undistorted view: the circle about the recorded
    disc's rim brought back to ideal pixels, its radius the rim's nearest point (inside it)."""
    t = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    out = []
    for (cx, cy, r), d in zip(circles, distortions):
        rim = d.undistort(np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], axis=-1))
        centre = rim.mean(axis=0)
        out.append((float(centre[0]), float(centre[1]), float(np.min(np.hypot(*(rim - centre).T)))))
    return tuple(out)


# ------------------------------------------------------------------------------------------------
def _luminance(views, flat_views, masks) -> np.ndarray:
    """(V, h, w) float32 luminance of the views, divided by the flat's where it is given."""
    lum = np.asarray(views, np.float32)
    lum = lum.mean(axis=3) if lum.ndim == 4 else lum
    if flat_views is None:
        return np.ascontiguousarray(lum, np.float32)
    flat = np.asarray(flat_views, np.float32)
    flat = flat.mean(axis=3) if flat.ndim == 4 else flat
    out = np.zeros_like(lum)
    for k in range(len(lum)):
        bright = float(np.percentile(flat[k][masks[k]], 95)) if masks[k].any() else 0.0
        ok = flat[k] > FLAT_FLOOR * bright
        np.divide(lum[k], flat[k], out=out[k], where=ok)
    return out


def _correspondences(lum, hom, dist, masks, circles, tile: int) -> list:
    """For every plane and pair of views (j, k): (depth, j, k, recorded points of view k,
    recorded points of view j) of the tiles matched between the views undistorted by ``dist``."""
    shape = masks.shape[1:]
    mx, my = undistortion_maps(dist, shape)
    skip = tuple(k for k, d in enumerate(dist) if d.is_identity)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    inner = np.stack([(xx - cx) ** 2 + (yy - cy) ** 2 <= (r * (1 - _RIM_FRACTION)) ** 2 for cx, cy, r in circles]) & masks
    ideal_masks = undistort_masks(inner, dist, maps=(mx, my))
    out = []
    h, w = shape
    for z, by_pair in hom.items():
        ideal = remap_views(lum[z][..., None], mx, my, skip=skip)[..., 0]
        for (j, k), hjk in by_pair.items():
            warped = cv2.warpPerspective(ideal[k], hjk, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            wmask = cv2.warpPerspective(ideal_masks[k].view(np.uint8), hjk, (w, h), flags=cv2.INTER_NEAREST) > 0
            centres, shifts = local_shifts(ideal[j], warped, wmask & ideal_masks[j], tile_px=tile)
            view_pts = apply_homography(np.linalg.inv(hjk), centres + shifts)
            out.append((z, j, k, dist[k].distort(view_pts), dist[j].distort(centres)))
    return out


def _solve(corr, dist, hom, radius: float):
    """Levenberg-Marquardt (Huber-weighted) over every view's coefficients and every plane's and
    pair's homography. Returns (distortions, homographies {z: {(j, k): H}}, RMS residual px)."""
    nterm = len(POLYNOMIAL_TERMS)
    ncoef = 2 * nterm * len(dist)
    keys = [(z, j, k) for z, j, k, _, _ in corr]
    coef = np.concatenate([np.concatenate([np.real(d.coefficients), np.imag(d.coefficients)]) for d in dist])
    # Homographies in normalised coordinates (conditioning): u~ = (u - c0) / s0.
    c0 = np.array(dist[0].centre_px)
    s0 = radius
    t = np.array([[1 / s0, 0, -c0[0] / s0], [0, 1 / s0, -c0[1] / s0], [0, 0, 1]])
    hv = np.concatenate([_h_vector(t @ hom[z][(j, k)] @ np.linalg.inv(t)) for z, j, k in keys])

    def residuals(coef, hv, jacobian: bool):
        ds = _distortions(dist, coef)
        out, blocks = [], []
        for n, (z, j, k, xk, xj) in enumerate(corr):
            uk, jk = _inverse_and_jacobian(ds[k], xk, jacobian)
            uj, jj = _inverse_and_jacobian(ds[j], xj, jacobian)
            pred, dp_dh, dp_du = _project(hv[8 * n : 8 * n + 8], (uk - c0) / s0)
            out.append(s0 * pred - (uj - c0))  # pixels
            if not jacobian:
                continue
            m = len(xk)
            block = np.zeros((2 * m, ncoef + 8 * len(corr)))
            block[:, ncoef + 8 * n : ncoef + 8 * n + 8] = s0 * dp_dh.reshape(2 * m, 8)
            # d(prediction)/d(view k's coefficients) through u_k; the reference point u_j moves too.
            block[:, _cols(k, nterm)] += np.einsum("nab,nbc->nac", dp_du, jk).reshape(2 * m, -1)
            block[:, _cols(j, nterm)] -= jj.reshape(2 * m, -1)
            blocks.append(block)
        return out, blocks

    def cost(res, weights, coef):
        total = sum(float(np.sum(w[:, None] * r * r)) for r, w in zip(res, weights))
        return total + float(np.sum((_RIDGE_WEIGHT * radius * coef) ** 2))

    mu = 1e-3
    for _ in range(_LM_ITERATIONS):
        res, blocks = residuals(coef, hv, True)
        # Huber weights (a tile that locked on the wrong speckle counts linearly).
        weights = [np.minimum(1.0, _ROBUST_SCALE_PX / np.maximum(np.hypot(*r.T), 1e-12)) for r in res]
        a = np.concatenate([b * np.repeat(np.sqrt(w), 2)[:, None] for b, w in zip(blocks, weights)])
        rhs = -np.concatenate([(r * np.sqrt(w)[:, None]).ravel() for r, w in zip(res, weights)])
        normal, grad = a.T @ a, a.T @ rhs
        normal[:ncoef, :ncoef] += np.eye(ncoef) * (_RIDGE_WEIGHT * radius) ** 2
        grad[:ncoef] -= (_RIDGE_WEIGHT * radius) ** 2 * coef
        before = cost(res, weights, coef)
        diag = np.maximum(np.diag(normal), 1e-12)
        accepted = False
        for _ in range(12):
            step = np.linalg.solve(normal + mu * np.diag(diag), grad)
            new_coef = coef + step[:ncoef]
            new_hv = hv + step[ncoef:]
            after = cost(residuals(new_coef, new_hv, False)[0], weights, new_coef)
            if after < before:
                coef, hv, accepted = new_coef, new_hv, True
                mu = max(mu / 4, 1e-9)
                break
            mu *= 8
        if not accepted or before - after < _LM_TOLERANCE * before:
            break
    ds = _distortions(dist, coef)
    out_h = {}
    for n, (z, j, k) in enumerate(keys):
        hn = np.linalg.inv(t) @ _h_matrix(hv[8 * n : 8 * n + 8]) @ t
        out_h.setdefault(z, {})[(j, k)] = hn / hn[2, 2]
    final = residuals(coef, hv, False)[0]
    rms = float(np.sqrt(np.mean(np.concatenate([np.sum(r * r, axis=1) for r in final]))))
    return ds, out_h, rms


def _cols(view: int, nterm: int) -> slice:
    return slice(2 * nterm * view, 2 * nterm * (view + 1))


def _distortions(dist, coef) -> tuple:
    nterm = len(POLYNOMIAL_TERMS)
    out = []
    for k, d in enumerate(dist):
        c = coef[2 * nterm * k : 2 * nterm * (k + 1)]
        out.append(d.with_coefficients(c[:nterm] + 1j * c[nterm:]))
    return tuple(out)


def _inverse_and_jacobian(d, x, with_jacobian: bool):
    """Ideal points u = F^-1(x) (m, 2) and du/dcoef (m, 2, 2 nterm): from F(u) = x,
    ``du = -J_F(u)^-1 dF/dcoef``."""
    u = d.undistort(x)
    if not with_jacobian:
        return u, None
    s = d.scale_px
    z = ((u[:, 0] - d.centre_px[0]) + 1j * (u[:, 1] - d.centre_px[1])) / s
    basis = polynomial_basis(z)  # (m, P): dF/d(real c_j) = s phi_j, dF/d(imag c_j) = s i phi_j
    dfdc = np.concatenate([np.stack([basis.real, basis.imag], axis=1),
                           np.stack([-basis.imag, basis.real], axis=1)], axis=2) * s  # (m, 2, 2P)
    dzx, dzy = _basis_derivatives(z)
    coef = np.asarray(d.coefficients, np.complex128)
    ddx, ddy = dzx @ coef, dzy @ coef  # dD/dx, dD/dy (normalised units cancel)
    # -J_F^-1 dF/dcoef, the 2 x 2 inverse written out.
    a, b, c, e = 1 + ddx.real, ddy.real, ddx.imag, 1 + ddy.imag
    det = a * e - b * c
    inv = np.stack([np.stack([e, -b], axis=1), np.stack([-c, a], axis=1)], axis=1) / det[:, None, None]
    return u, -np.einsum("nab,nbc->nac", inv, dfdc)


def _basis_derivatives(z):
    """d/dx and d/dy of every monomial z^a conj(z)^b, (m, P) complex each."""
    zb = np.conj(z)
    dx = np.empty(z.shape + (len(POLYNOMIAL_TERMS),), np.complex128)
    dy = np.empty_like(dx)
    for n, (a, b) in enumerate(POLYNOMIAL_TERMS):
        ta = a * z ** (a - 1) * zb**b if a else 0.0
        tb = b * z**a * zb ** (b - 1) if b else 0.0
        dx[..., n] = ta + tb
        dy[..., n] = 1j * (ta - tb)
    return dx, dy


def _project(h8, p):
    """Projective map of points p (m, 2) by H (8 entries, H[2, 2] = 1): values (m, 2), their
    derivatives by the entries (m, 2, 8) and by the points (m, 2, 2)."""
    x, y = p[:, 0], p[:, 1]
    X = h8[0] * x + h8[1] * y + h8[2]
    Y = h8[3] * x + h8[4] * y + h8[5]
    W = h8[6] * x + h8[7] * y + 1.0
    px, py = X / W, Y / W
    m = len(p)
    dh = np.zeros((m, 2, 8))
    dh[:, 0, 0], dh[:, 0, 1], dh[:, 0, 2] = x / W, y / W, 1 / W
    dh[:, 1, 3], dh[:, 1, 4], dh[:, 1, 5] = x / W, y / W, 1 / W
    dh[:, 0, 6], dh[:, 0, 7] = -x * px / W, -y * px / W
    dh[:, 1, 6], dh[:, 1, 7] = -x * py / W, -y * py / W
    du = np.empty((m, 2, 2))
    du[:, 0, 0], du[:, 0, 1] = (h8[0] - px * h8[6]) / W, (h8[1] - px * h8[7]) / W
    du[:, 1, 0], du[:, 1, 1] = (h8[3] - py * h8[6]) / W, (h8[4] - py * h8[7]) / W
    return np.stack([px, py], axis=1), dh, du


def _h_vector(h: np.ndarray) -> np.ndarray:
    h = h / h[2, 2]
    return h.ravel()[:8].copy()


def _h_matrix(v: np.ndarray) -> np.ndarray:
    return np.append(v, 1.0).reshape(3, 3)


def _normalised(h: np.ndarray) -> np.ndarray:
    return h / h[2, 2]


def _solve_homography(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The homography H (H[2, 2] = 1) with ``v ~ H u`` by linear least squares on coordinates
    centred and scaled for conditioning (for the near-translations between the ring's views,
    the algebraic error is the geometric one to a part in ten thousand)."""
    c = np.concatenate([u, v]).mean(axis=0)
    s = max(float(np.abs(np.concatenate([u, v]) - c).max()), 1.0)
    a, b = (u - c) / s, (v - c) / s
    n = len(a)
    A = np.zeros((2 * n, 8))
    A[0::2, 0:2], A[0::2, 2] = a, 1.0
    A[1::2, 3:5], A[1::2, 5] = a, 1.0
    A[0::2, 6:8] = -b[:, :1] * a
    A[1::2, 6:8] = -b[:, 1:] * a
    sol, *_ = np.linalg.lstsq(A, b.ravel(), rcond=None)
    hn = np.append(sol, 1.0).reshape(3, 3)
    t = np.array([[1 / s, 0, -c[0] / s], [0, 1 / s, -c[1] / s], [0, 0, 1]])
    h = np.linalg.inv(t) @ hn @ t
    return h / h[2, 2]
