"""What a real mini-lens does to its view, and how the split undoes it: distortion and vignetting.

Each view of the ring is a pinhole camera only for ideal mini-lenses. A real mini-lens moves
every image point radially (barrel or pincushion: ``k1``, ``k2``) and, when its elements are
not quite centred, tangentially (decentring: ``p1``, ``p2``), each lens its own way; and each
lens lets through its own share of light, falling off towards the rim (vignetting).

:class:`Distortion` is that map for one view, in the view's own pixels: from where the pinhole
camera would put a point (the *ideal* position) to where the lens puts it (the *recorded*
position). The twin renders a physical lens (:class:`LensDistortion`: Brown-Conrady radial and
decentring terms about the lens's axis, in its tilted frame); the calibration fits a
:class:`PolynomialDistortion`, which needs no centre to be found; the split undoes either
with one remap per view (:func:`undistortion_maps`: for every ideal pixel, the recorded
position to sample, so no inversion is needed). :class:`FlatField` is each view's relative
illumination measured on a flat (white) frame; dividing by it makes the views equally bright.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from lfring.core.records import record_repr
from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError

__all__ = [
    "COEFFICIENTS",
    "FLAT_FLOOR",
    "POLYNOMIAL_TERMS",
    "Distortion",
    "FlatField",
    "LensDistortion",
    "PolynomialDistortion",
    "distortion_from_dict",
    "polynomial_basis",
    "remap_views",
    "undistortion_maps",
]

COEFFICIENTS = ("k1", "k2", "p1", "p2")
"""The distortion coefficients of :class:`LensDistortion`, in the order they are stored."""

FLAT_FLOOR = 0.2
"""Fraction of a flat frame's bright level below which a pixel is not divided by it: the rim of a
view's disc, where so little light arrives that dividing would amplify noise into glare."""

#: fixed-point steps of :meth:`Distortion.undistort`; each shrinks the error by the
#: distortion's slope (a few hundredths for a lens that moves its rim by a few per cent).
_UNDISTORT_ITERATIONS = 30
_UNDISTORT_TOLERANCE_PX = 1e-7
#: node spacing of :meth:`Distortion.undistort_box`, pixels.
_GRID_STEP_PX = 8


@dataclass(frozen=True)
class Distortion(abc.ABC):
    """A map of one view's pixels from where a pinhole camera would put a point (ideal) to where
    the lens puts it (recorded), about a centre and normalised by a length: the common part of
    :class:`LensDistortion` (a lens's physical model) and :class:`PolynomialDistortion` (what a
    calibration fits).

    Parameters
    ----------
    centre_px : (float, float)
        (x, y) of the centre in the view's pixels (pixel centres at integers).
    scale_px : float
        The length that normalises positions: ``n = (u - centre) / scale_px``.
    """

    centre_px: tuple[float, float]
    scale_px: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_px", _pair(self.centre_px, "centre_px"))
        object.__setattr__(self, "scale_px", check_number(self.scale_px, "distortion scale_px", above=0.0,
                                                          what="a length in pixels"))

    __repr__ = record_repr

    @property
    @abc.abstractmethod
    def is_identity(self) -> bool:
        """True when the map moves no point."""

    @abc.abstractmethod
    def _normalised_forward(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The distorted normalised positions of the undistorted ones ``(x, y)``."""

    def shifted(self, dx_px: float, dy_px: float):
        """The same distortion in a pixel frame whose origin is moved: ``centre + (dx, dy)``
        (``shifted(-x0, -y0)`` expresses a raw-frame distortion in a view cut at (x0, y0))."""
        import dataclasses

        cx, cy = self.centre_px
        return dataclasses.replace(self, centre_px=(cx + dx_px, cy + dy_px))

    def distort(self, xy) -> np.ndarray:
        """Recorded pixel positions (..., 2) of ideal pixel positions (..., 2) (x, y)."""
        p = _points(xy)
        if self.is_identity:
            return p.copy()
        cx, cy = self.centre_px
        s = self.scale_px
        xd, yd = self._normalised_forward((p[..., 0] - cx) / s, (p[..., 1] - cy) / s)
        return np.stack([cx + s * xd, cy + s * yd], axis=-1)

    def undistort(self, xy) -> np.ndarray:
        """Ideal pixel positions (..., 2) of recorded ones: the inverse of :meth:`distort`, by
        fixed-point iteration (exact to far below a thousandth of a pixel for any lens whose
        distortion moves neighbouring points by less than their distance)."""
        x = _points(xy)
        u = x.copy()
        if self.is_identity:
            return u
        for _ in range(_UNDISTORT_ITERATIONS):
            err = x - self.distort(u)
            u += err
            if float(np.max(np.abs(err), initial=0.0)) < _UNDISTORT_TOLERANCE_PX:
                break
        return u

    def undistort_box(self, x0: int, y0: int, w: int, h: int, *, step: int = _GRID_STEP_PX) -> np.ndarray:
        """(h, w, 2) float64 ideal positions of every pixel (x, y) of the box at (x0, y0): the
        inverse solved exactly every ``step`` pixels and interpolated (bicubic spline) in
        between, which for a distortion (smooth over hundreds of pixels) is exact to far below a
        thousandth of a pixel, at a small fraction of the cost of solving every pixel."""
        gx = np.arange(x0 - 2 * step, x0 + w + 3 * step, step, dtype=np.float64)
        gy = np.arange(y0 - 2 * step, y0 + h + 3 * step, step, dtype=np.float64)
        nodes = np.stack(np.meshgrid(gx, gy), axis=-1)
        shift = self.undistort(nodes) - nodes
        xs = np.arange(x0, x0 + w, dtype=np.float64)
        ys = np.arange(y0, y0 + h, dtype=np.float64)
        # A cubic spline through the nodes (OpenCV's remap would round the positions), both
        # components at once: one pair of weight matrices.
        out = np.ascontiguousarray(np.moveaxis(_bicubic(gy, gx, np.moveaxis(shift, -1, 0), ys, xs), 0, -1))
        out[..., 0] += xs[None, :]
        out[..., 1] += ys[:, None]
        return out

    def displacement_px(self, radius_px: float | None = None, *, centre_px=None, samples: int = 360) -> float:
        """Largest distance (px) between an ideal point and its recorded position on the circle
        of ``radius_px`` (default ``scale_px``) about ``centre_px`` (default the centre)."""
        r = self.scale_px if radius_px is None else float(radius_px)
        cx, cy = self.centre_px if centre_px is None else centre_px
        t = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
        pts = np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], axis=-1)
        return float(np.max(np.hypot(*(self.distort(pts) - pts).T)))


@dataclass(frozen=True)
class LensDistortion(Distortion):
    """The distortion of one view by a real lens: Brown-Conrady radial and decentring terms,
    about the lens's axis, in the lens's own (possibly tilted) frame.

    Parameters
    ----------
    centre_px, scale_px
        As :class:`Distortion`. The twin centres each lens's distortion where the lens's centre
        projects onto the sensor, with ``scale_px`` the lens's distance to the sensor in pixels
        (so ``n`` is the tangent of the ray's angle behind the lens: OpenCV's normalised
        coordinates, and the coefficients are OpenCV's).
    k1, k2 : float
        Radial coefficients: ``n (1 + k1 r^2 + k2 r^4)``, r = |n|; negative is barrel.
    p1, p2 : float
        Decentring (tangential) coefficients, as OpenCV's.
    tilt_rad : (float, float)
        Rotation of the lens about the x and then the y axis, radians: the distortion acts in the
        lens's own frame. A tilted thin lens does not move the chief ray, so a tilt alone
        changes nothing.

    Notes
    -----
    With ``n = (x, y)``, ``r^2 = x^2 + y^2``, the recorded normalised position is

        x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)
        y_d = y (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y^2) + 2 p2 x y

    (OpenCV's model without k3 and the rational terms), then ``centre + scale_px n_d``. With a
    tilt R, the ray (x, y, 1) is taken into the lens frame by R^T, distorted there and brought
    back by R before meeting the sensor again.

    Examples
    --------
    >>> d = LensDistortion((350.0, 350.0), 350.0, k1=-0.03)
    >>> d.distort([[700.0, 350.0]]).round(3).tolist()  # the rim moves in by 3 % of the radius
    [[689.5, 350.0]]
    >>> d.undistort(d.distort([[700.0, 350.0]])).round(6).tolist()
    [[700.0, 350.0]]
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    tilt_rad: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in COEFFICIENTS:
            object.__setattr__(self, name, check_number(getattr(self, name), f"distortion {name}"))
        tilt = _pair(self.tilt_rad, "tilt_rad")
        if max(abs(tilt[0]), abs(tilt[1])) >= 0.5:
            raise InvalidInputError(f"a lens tilt must be small (under 0.5 rad about each axis), got {tilt}")
        object.__setattr__(self, "tilt_rad", tilt)

    @property
    def coefficients(self) -> tuple[float, float, float, float]:
        """(k1, k2, p1, p2)."""
        return self.k1, self.k2, self.p1, self.p2

    @property
    def is_identity(self) -> bool:
        """True when the lens moves no point (every coefficient 0; a tilt alone moves nothing)."""
        return not any(self.coefficients)

    def _normalised_forward(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tx, ty = self.tilt_rad
        if tx or ty:
            rot = _rotation(tx, ty)
            # Into the lens frame (R^T), distorted there, back (R); the chief ray keeps its line.
            dx, dy, dz = _rotate(rot.T, x, y)
            xd, yd = _brown_conrady(dx / dz, dy / dz, self.coefficients)
            ex, ey, ez = _rotate(rot, xd, yd)
            return ex / ez, ey / ez
        return _brown_conrady(x, y, self.coefficients)

    def to_dict(self) -> dict:
        """The JSON form (plain numbers), read back by :func:`distortion_from_dict`."""
        out = {"model": "brown-conrady", "centre_view_px": list(self.centre_px), "scale_px": self.scale_px,
               **{name: getattr(self, name) for name in COEFFICIENTS}}
        if any(self.tilt_rad):
            out["tilt_rad"] = list(self.tilt_rad)
        return out


POLYNOMIAL_TERMS = tuple((a, d - a) for d in range(2, 6) for a in range(d + 1) if (a, d - a) != (2, 0))
"""The monomials ``z^a conj(z)^b`` (z = x + i y, normalised) of :class:`PolynomialDistortion`:
every degree from 2 to 5 but ``z^2``, which the homographies absorb (with ``z conj(z)`` it spans
the quadratic maps ``n (g . n)`` of a projective change of frame)."""


@dataclass(frozen=True)
class PolynomialDistortion(Distortion):
    """A distortion as a polynomial of the normalised position, as the calibration fits it.

    The recorded position is ``u + scale_px D(z)`` with ``z = (u - centre) / scale_px`` read as
    a complex number ``x + i y`` and ``D(z) = sum_j c_j z^a_j conj(z)^b_j`` over
    :data:`POLYNOMIAL_TERMS`: every smooth map of degrees 2 to 5 but its affine part (which a
    view's homographies absorb). Radial distortion about any point (``k1`` is the term
    ``z^2 conj(z) = r^2 z``, ``k2`` the term ``r^4 z``), decentring and a lens's small tilt are
    all such maps, exactly or to a small fraction of a pixel: no centre has to be found.

    Parameters
    ----------
    centre_px, scale_px
        As :class:`Distortion`; the calibration uses the view's disc centre and radius.
    coefficients : tuple of complex
        One per term of :data:`POLYNOMIAL_TERMS` (all 0: the identity).

    Examples
    --------
    >>> terms = [0j] * len(POLYNOMIAL_TERMS)
    >>> terms[POLYNOMIAL_TERMS.index((2, 1))] = -0.03  # r^2 z: barrel, 3 % of the radius at the rim
    >>> d = PolynomialDistortion((350.0, 350.0), 350.0, tuple(terms))
    >>> d.distort([[700.0, 350.0]]).round(3).tolist()
    [[689.5, 350.0]]
    """

    coefficients: tuple = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        c = tuple(complex(v) for v in self.coefficients) if self.coefficients else (0j,) * len(POLYNOMIAL_TERMS)
        if len(c) != len(POLYNOMIAL_TERMS) or not all(np.isfinite(v.real) and np.isfinite(v.imag) for v in c):
            raise InvalidInputError(f"a polynomial distortion has {len(POLYNOMIAL_TERMS)} finite coefficients, got {len(c)}")
        object.__setattr__(self, "coefficients", c)

    @property
    def is_identity(self) -> bool:
        """True when every coefficient is 0."""
        return not any(self.coefficients)

    def _normalised_forward(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.displacement(x + 1j * y)
        return x + d.real, y + d.imag

    def displacement(self, z: np.ndarray) -> np.ndarray:
        """``D(z)`` (complex, normalised) at normalised complex positions ``z``."""
        z = np.asarray(z, np.complex128)
        zp, zbp = _powers(z)
        out = np.zeros_like(z)
        for (a, b), c in zip(POLYNOMIAL_TERMS, self.coefficients):
            if c:
                out += c * (zp[a] * zbp[b])
        return out

    def with_coefficients(self, coefficients) -> PolynomialDistortion:
        """The same centre and scale with other coefficients."""
        import dataclasses

        return dataclasses.replace(self, coefficients=tuple(coefficients))

    def to_dict(self) -> dict:
        """The JSON form (plain numbers), read back by :func:`distortion_from_dict`."""
        return {"model": "polynomial", "centre_view_px": list(self.centre_px), "scale_px": self.scale_px,
                "terms": [[a, b, c.real, c.imag] for (a, b), c in zip(POLYNOMIAL_TERMS, self.coefficients) if c]}


def polynomial_basis(z: np.ndarray) -> np.ndarray:
    """(..., P) complex: the monomials of :data:`POLYNOMIAL_TERMS` at normalised positions ``z``."""
    z = np.asarray(z, np.complex128)
    zp, zbp = _powers(z)
    out = np.empty(z.shape + (len(POLYNOMIAL_TERMS),), np.complex128)
    for j, (a, b) in enumerate(POLYNOMIAL_TERMS):
        np.multiply(zp[a], zbp[b], out=out[..., j])
    return out


def _powers(z: np.ndarray) -> tuple[list, list]:
    """z^0..z^5 and conj(z)^0..conj(z)^5 by repeated products (complex ** is far slower)."""
    top = max(max(a, b) for a, b in POLYNOMIAL_TERMS)
    zp = [np.ones_like(z), z]
    for _ in range(top - 1):
        zp.append(zp[-1] * z)
    zbp = [np.conj(p) for p in zp]
    return zp, zbp


def distortion_from_dict(data) -> Distortion:
    """A distortion from its JSON form (``to_dict``); raises InvalidInputError naming the bad key."""
    if not isinstance(data, dict):
        raise InvalidInputError(f"a lens distortion must be an object of keys, got {type(data).__name__}")
    model = data.get("model")
    common = {"model", "centre_view_px", "scale_px"}
    known = common | ({"tilt_rad", *COEFFICIENTS} if model == "brown-conrady" else {"terms"})
    if model not in ("brown-conrady", "polynomial"):
        raise InvalidInputError(f"a lens distortion's 'model' must be 'brown-conrady' or 'polynomial', got {model!r}")
    unknown = sorted(set(data) - known)
    if unknown:
        raise InvalidInputError(f"unknown lens distortion key(s) {unknown}; valid: {sorted(known)}")
    for key in ("centre_view_px", "scale_px"):
        if key not in data:
            raise InvalidInputError(f"a lens distortion needs '{key}'")
    if model == "brown-conrady":
        return LensDistortion(centre_px=data["centre_view_px"], scale_px=data["scale_px"],
                              tilt_rad=data.get("tilt_rad", (0.0, 0.0)), **{k: data.get(k, 0.0) for k in COEFFICIENTS})
    coef = [0j] * len(POLYNOMIAL_TERMS)
    terms = data.get("terms", [])
    if not isinstance(terms, list):
        raise InvalidInputError("a polynomial distortion's 'terms' must be a list of [a, b, real, imag]")
    for t in terms:
        ok = isinstance(t, list) and len(t) == 4 and (t[0], t[1]) in POLYNOMIAL_TERMS
        if not ok:
            raise InvalidInputError(f"a polynomial distortion term must be [a, b, real, imag] with (a, b) one of "
                                    f"{list(POLYNOMIAL_TERMS)}, got {t!r}")
        coef[POLYNOMIAL_TERMS.index((t[0], t[1]))] = complex(check_number(t[2], "term real part"),
                                                             check_number(t[3], "term imaginary part"))
    return PolynomialDistortion(centre_px=data["centre_view_px"], scale_px=data["scale_px"], coefficients=tuple(coef))


def _grid_nodes(n: int, step: int) -> np.ndarray:
    """Pixel positions of a flat-field grid's nodes along a side of ``n`` pixels: every ``step``
    pixels from 0, and the last pixel."""
    nodes = np.arange(0, n - 1, step)
    return np.append(nodes, n - 1) if n > 1 else np.zeros(1, int)


def _spline_weights(nodes: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(len(at), n) weights of the cubic interpolating spline through ``n`` >= 4 increasing
    ``nodes`` with not-a-knot ends (FITPACK's, as scipy's ``RectBivariateSpline`` with ``s=0``
    builds it), evaluated at ``at``: the spline's values there are ``weights @ values``.
    Positions past the end nodes take the end node's value, as scipy's evaluation does."""
    x = np.asarray(nodes, dtype=np.float64)
    t = np.clip(np.asarray(at, dtype=np.float64), x[0], x[-1])
    n = len(x)
    h = np.diff(x)
    # Second derivatives m from the values y: a m = r y (the interior continuity of the first
    # derivative; the third derivative continuous across the second and the last but one node).
    a = np.zeros((n, n))
    r = np.zeros((n, n))
    i = np.arange(1, n - 1)
    a[i, i - 1], a[i, i], a[i, i + 1] = h[:-1], 2.0 * (h[:-1] + h[1:]), h[1:]
    r[i, i - 1], r[i, i], r[i, i + 1] = 6.0 / h[:-1], -6.0 / h[:-1] - 6.0 / h[1:], 6.0 / h[1:]
    a[0, :3] = h[1], -(h[0] + h[1]), h[0]
    a[-1, -3:] = h[-1], -(h[-2] + h[-1]), h[-2]
    c = np.linalg.solve(a, r)  # m = c y
    k = np.clip(np.searchsorted(x, t, side="right") - 1, 0, n - 2)
    hk = h[k]
    b = (t - x[k]) / hk
    a_ = 1.0 - b
    rows = np.arange(len(t))
    w = (((a_ ** 3 - a_) * hk * hk / 6.0)[:, None] * c[k] + ((b ** 3 - b) * hk * hk / 6.0)[:, None] * c[k + 1])
    w[rows, k] += a_
    w[rows, k + 1] += b
    return w


def _bicubic(ys, xs, values: np.ndarray, rows, cols) -> np.ndarray:
    """The bicubic interpolating spline through ``values`` (..., len(ys), len(xs)) at the nodes
    ``ys`` x ``xs`` (each at least 4, increasing), at every (row, col) of ``rows`` x ``cols``:
    (..., len(rows), len(cols)). Separable: the same numbers as scipy's
    ``RectBivariateSpline(ys, xs, v, kx=3, ky=3)(rows, cols)``, to rounding, without
    importing scipy.interpolate (which costs a command's start half a second)."""
    wy, wx = _spline_weights(ys, rows), _spline_weights(xs, cols)
    return np.matmul(np.matmul(wy, np.asarray(values, dtype=np.float64)), wx.T)


def _points(xy) -> np.ndarray:
    p = np.asarray(xy, dtype=np.float64)
    if p.shape[-1:] != (2,):
        raise InvalidInputError(f"points must be (..., 2) (x, y), got shape {p.shape}")
    return p


def _pair(value, name: str) -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise InvalidInputError(f"distortion {name} must be two numbers, got {value!r}") from None
    return (check_number(a, f"distortion {name}[0]"), check_number(b, f"distortion {name}[1]"))


def _brown_conrady(x, y, coefficients):
    k1, k2, p1, p2 = coefficients
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    xy2 = 2.0 * x * y
    return (x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2)


def _rotation(tx: float, ty: float) -> np.ndarray:
    cx, sx, cy, sy = math.cos(tx), math.sin(tx), math.cos(ty), math.sin(ty)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return ry @ rx


def _rotate(rot: np.ndarray, x, y):
    """R (x, y, 1) component by component."""
    return (rot[0, 0] * x + rot[0, 1] * y + rot[0, 2],
            rot[1, 0] * x + rot[1, 1] * y + rot[1, 2],
            rot[2, 0] * x + rot[2, 1] * y + rot[2, 2])


def undistortion_maps(distortions, view_shape) -> tuple[np.ndarray, np.ndarray]:
    """The remap tables that undo every view's distortion: for each ideal pixel, the recorded
    position to sample (``cv2.remap(view, map_x[k], map_y[k], ...)``).

    Parameters
    ----------
    distortions : sequence of Distortion or None
        One per view (None: the view is left as it is).
    view_shape : (h, w)

    Returns
    -------
    map_x, map_y : (V, h, w) float32
        Recorded x and y of every ideal pixel.

    Examples
    --------
    >>> mx, my = undistortion_maps([None, LensDistortion((4.0, 3.0), 4.0, k1=0.01)], (7, 9))
    >>> mx.shape, float(mx[0, 3, 8]), round(float(mx[1, 3, 8]), 3)
    ((2, 7, 9), 8.0, 8.04)
    """
    h, w = (int(n) for n in view_shape)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    grid = np.stack([xx, yy], axis=-1)
    mx = np.empty((len(distortions), h, w), np.float32)
    my = np.empty_like(mx)
    for k, d in enumerate(distortions):
        src = grid if d is None else d.distort(grid)
        mx[k], my[k] = src[..., 0], src[..., 1]
    return mx, my


def remap_views(views: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, *, skip=()) -> np.ndarray:
    """(V, h, w, C) views resampled (bilinear) at the maps of :func:`undistortion_maps`; views
    listed in ``skip`` are copied unchanged. Outside a view, its border pixels are repeated (the
    valid discs lie inside the views)."""
    out = np.empty_like(views)
    for k in range(len(views)):
        if k in skip:
            out[k] = views[k]
            continue
        res = cv2.remap(views[k], map_x[k], map_y[k], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out[k] = res.reshape(views[k].shape)
    return out



@dataclass(frozen=True, eq=False)
class FlatField:
    """How brightly each pixel of each view sees a uniformly lit white surface, relative to the
    brightest: the views' vignetting, each lens its own.

    Parameters
    ----------
    response : (V, h, w) float32
        In [0, 1], 1 at the brightest pixel of any view; measured on views split (and undistorted)
        as the frames it corrects are. Dividing a view by its response makes a white surface
        equally bright at every pixel of every view.

    Examples
    --------
    >>> import numpy as np
    >>> flat = FlatField.from_views(np.full((2, 4, 4, 3), [[[[0.8]]], [[[0.4]]]], np.float32))
    >>> [round(float(v), 3) for v in flat.apply(np.full((2, 4, 4, 1), 0.2, np.float32))[:, 0, 0, 0]]
    [0.2, 0.4]
    """

    response: np.ndarray
    _gains: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        r = np.asarray(self.response, dtype=np.float32)
        if r.ndim != 3 or min(r.shape) < 1 or not np.all(np.isfinite(r)):
            raise InvalidInputError(f"a flat field's response must be finite (V, h, w) values, got shape {r.shape}")
        r = np.clip(r, 0.0, 1.0)
        dark = [k for k in range(r.shape[0]) if not r[k].max() > 0.0]
        if dark:  # dividing by it would saturate the view: no flat frame's light reached it
            raise InvalidInputError(f"a flat field's response must be positive where its view sees light; view {dark[0]}'s "
                                    "is nowhere above 0")
        r.setflags(write=False)
        object.__setattr__(self, "response", r)

    __repr__ = record_repr

    @property
    def num_views(self) -> int:
        """Number of views V."""
        return self.response.shape[0]

    @property
    def view_shape(self) -> tuple[int, int]:
        """(h, w) of the views it corrects."""
        return self.response.shape[1], self.response.shape[2]

    @classmethod
    def from_views(cls, flat_views, *, smoothing_px: float = 1.0) -> FlatField:
        """The flat field of a flat (white) frame's views (V, h, w[, C]): their luminance, lightly
        smoothed (noise must not be divided into every frame; an average of many flat frames
        needs none), over its brightest level (the 99.9th percentile of all views, so that a
        few hot pixels do not set it)."""
        v = np.asarray(flat_views, dtype=np.float32)
        if v.ndim == 4:
            v = v.mean(axis=3)
        if v.ndim != 3:
            raise InvalidInputError(f"flat views must be (V, h, w) or (V, h, w, C), got shape {np.shape(flat_views)}")
        lum = np.stack([cv2.GaussianBlur(x, (0, 0), smoothing_px, borderType=cv2.BORDER_REPLICATE) if smoothing_px > 0
                        else x for x in v])
        level = float(np.percentile(lum, 99.9))
        if not level > 0.01:
            raise InvalidInputError("the flat frame is black where the views are; is it a flat (white) frame?")
        return cls(lum / level)

    def gains(self) -> np.ndarray:
        """(V, h, w) float32 ``1 / max(response, FLAT_FLOOR)``: where hardly any light arrives
        (the discs' outer rims, outside the valid discs) the views are not amplified further."""
        if "gains" not in self._gains:
            g = (np.float32(1.0) / np.maximum(self.response, np.float32(FLAT_FLOOR))).astype(np.float32)
            g.setflags(write=False)
            self._gains["gains"] = g
        return self._gains["gains"]

    def apply(self, views) -> np.ndarray:
        """(V, h, w, C) float32 views divided by the response (:meth:`gains`), clipped to [0, 1]
        (a value above 1 is a radiance that would have saturated the brightest pixel)."""
        v = np.asarray(views, dtype=np.float32)
        if v.ndim == 3:
            v = v[..., None]
        if v.shape[:3] != self.response.shape:
            raise InvalidInputError(
                f"the flat field is for {self.num_views} views of {self.view_shape[1]} x {self.view_shape[0]} px, "
                f"got views of shape {v.shape[:3]}")
        out = v * self.gains()[..., None]
        return np.clip(out, 0.0, 1.0, out=out)

    # -- a compact form for calibration files ----------------------------------------------
    def to_grid(self, step_px: int) -> np.ndarray:
        """(V, gh, gw) samples of the response every ``step_px`` pixels from pixel (0, 0), the
        last row and column on the views' far edges (what :meth:`from_grid` reads)."""
        step = check_int(step_px, "flat-field grid step", minimum=1)
        ys, xs = _grid_nodes(self.view_shape[0], step), _grid_nodes(self.view_shape[1], step)
        # Point samples: the response is already smoothed, and smoothing it again would flatten
        # the vignetting's curvature.
        return np.ascontiguousarray(self.response[:, ys][:, :, xs], dtype=np.float32)

    @classmethod
    def from_grid(cls, grid, step_px: int, view_shape) -> FlatField:
        """The flat field whose response :meth:`to_grid` sampled: interpolated (a bicubic
        spline) back to every pixel of views of ``view_shape`` (h, w)."""
        g = np.asarray(grid, dtype=np.float64)
        step = check_int(step_px, "flat-field grid step", minimum=1)
        h, w = (int(n) for n in view_shape)
        ys, xs = _grid_nodes(h, step), _grid_nodes(w, step)
        if g.ndim != 3 or g.shape[1:] != (len(ys), len(xs)):
            raise InvalidInputError(f"a flat-field grid of step {step} px for {w} x {h} px views must be (V, "
                                    f"{len(ys)}, {len(xs)}), got shape {g.shape}")
        # A cubic spline through the nodes (OpenCV's remap would round the positions to a 32nd
        # of a node spacing, half a pixel here).
        rows, cols = np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64)
        if min(len(ys), len(xs)) >= 4:
            return cls(_bicubic(ys, xs, g, rows, cols))
        from scipy.interpolate import RectBivariateSpline  # views of a few grid steps: a lower degree

        k = min(3, len(ys) - 1, len(xs) - 1)
        return cls(np.stack([RectBivariateSpline(ys, xs, x, kx=k, ky=k)(rows, cols) for x in g]))

    def same_as(self, other: FlatField) -> bool:
        """Whether two flat fields hold the same response (array equality)."""
        return isinstance(other, FlatField) and np.array_equal(self.response, other.response)
