"""The defocus blur of the twin: the pillbox kernel, and the blur of a rendered edge against the
paraxial disc diameter."""

import numpy as np
import pytest

from lfring.optics import paraxial
from lfring.synth import Plane, Scene, Texture, render
from lfring.synth.defocus import disc_kernel


def test_defocus_blur_width_matches_spec(prototype):
    """A step edge at 1.0 m, focus at 0.3 m: the edge's line-spread width gives the disc
    diameter (variance of a disc's LSF is D^2/16), compared with 2 Rml |c - c'| / c'."""
    z = 1.0
    tex = Texture("checker", square_m=0.2, colors=((0.1, 0.1, 0.1), (0.9, 0.9, 0.9)))
    scene = Scene((Plane(z, (0.4, 0.4), tex),))
    kw = dict(binning=2, pattern=None, vignetting=False)
    widths = {}
    for defocus in (False, True):
        r = render(prototype, scene, defocus=defocus, **kw)
        v = r.views[0, ..., 1]
        vh, vw = v.shape
        esf = v[vh // 8 : vh // 3].mean(axis=0).astype(np.float64)  # rows away from the horizontal edge
        lsf = np.abs(np.diff(esf))
        peak = int(np.argmax(lsf))
        win = lsf[peak - 20 : peak + 21]
        xs = np.arange(win.size)
        mu = (win * xs).sum() / win.sum()
        widths[defocus] = (win * (xs - mu) ** 2).sum() / win.sum()
    measured = 4.0 * np.sqrt(widths[True] - widths[False])
    expected = float(paraxial.blur_diameter_m(r.device, z)) / r.device.pixel_pitch_m
    assert expected == pytest.approx(7.86, abs=0.05)  # SPEC 2.3: ~16 px at full resolution
    assert measured == pytest.approx(expected, rel=0.10)


def test_disc_kernel():
    assert disc_kernel(0.5) is None
    k = disc_kernel(7.0)
    assert k.shape == (7, 7) and k.sum() == pytest.approx(1.0)
    yy, xx = np.indices(k.shape) - 3
    assert (k * (xx**2 + yy**2)).sum() == pytest.approx(7.0**2 / 8, rel=0.05)  # E[r^2] = R^2/2
