"""The rendered parts the inspection tests judge, and their ground truth: shared by the tests of
lfring.inspect (tests/inspect/conftest.py renders them once per session)."""

from pathlib import Path

import cv2
import numpy as np

from lfring.calibration.defaults import default_calibration

PLANE, TOL = 0.3, 0.008


def truth_deviation(r, cal, plane_m):
    """Plane minus true depth (+ towards the camera) in the central frame: each view's ground
    truth carried by its plane homography (its rectangle may sit a pixel off the calibration's)."""
    h, w = cal.layout.view_shape
    acc, cnt = np.zeros((h, w)), np.zeros((h, w))
    with np.errstate(invalid="ignore"):
        for k, hk in enumerate(cal.homographies(plane_m)):
            t = np.eye(3)
            t[:2, 2] = np.subtract(r.layout.rects[k][:2], cal.layout.rects[k][:2])
            z = r.depth_m[k]
            ok = np.isfinite(z).astype(np.float32)
            dev = np.where(np.isfinite(z), plane_m - z, 0).astype(np.float32)
            wo = cv2.warpPerspective(ok, hk @ t, (w, h), flags=cv2.INTER_NEAREST)
            acc += cv2.warpPerspective(dev, hk @ t, (w, h), flags=cv2.INTER_NEAREST) * wo
            cnt += wo
        return np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan)


def truth_defects(dev_m, tol_m):
    """Planted defects: regions deviating by more than tol/2 (and less than 5 cm: not the belt)."""
    out = []
    d = np.nan_to_num(dev_m)
    for sign in (1, -1):
        m = (sign * d > tol_m / 2) & (np.abs(d) < 0.05)
        n, lab, st, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8))
        out += [(tuple(st[j, :4]), float(sign * np.max(sign * d[lab == j]))) for j in range(1, n) if st[j, 4] >= 50]
    return out


def overlap(a, b):
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


def views_of(path):
    import lfring

    image = lfring.demosaic(lfring.load_raw(path))
    cal = default_calibration((image.shape[1], image.shape[0]))[0]
    return lfring.split_views(image, cal.layout), cal


DATA = Path(__file__).resolve().parents[2] / "data" / "synthetic"
