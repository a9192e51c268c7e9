"""The torch/kornia plane sweep against the NumPy/OpenCV reference, on the CPU."""

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")

from lfring.calibration import RingCalibration  # noqa: E402
from lfring.core.filters import BoxTorch  # noqa: E402
from lfring.depth import COSTS, estimate_depth  # noqa: E402
from lfring.depth.aggregation import GuidedTorch  # noqa: E402
from lfring.depth.selection import RunningMinimum, RunningMinimumTorch  # noqa: E402
from lfring.depth.sweep import slices  # noqa: E402
from lfring.errors import InvalidInputError  # noqa: E402
from lfring.synth import render  # noqa: E402
from lfring.synth.presets import three_depth_scene  # noqa: E402


@pytest.fixture(scope="module")
def twin(prototype):
    r = render(prototype, three_depth_scene(), binning=4)
    return r.views, RingCalibration.from_optics(r.device, layout=r.layout)


def _agreement(a, b):
    both = np.isfinite(a.depth_m) & np.isfinite(b.depth_m)
    rel = np.abs(b.depth_m[both] - a.depth_m[both]) / a.depth_m[both]
    dconf = np.abs(b.confidence[both] - a.confidence[both])
    return both, np.mean(rel <= 0.005), np.mean(dconf <= 0.02)


@pytest.mark.parametrize("reference", [0, "center"])
@pytest.mark.parametrize("aggregation", ["box", "guided"])
@pytest.mark.parametrize("cost", COSTS)
def test_parity_with_numpy(twin, cost, aggregation, reference, device):
    if cost == "lcn-halves":  # the whole volume and the halves' volume beside it
        return _halves_parity(twin, aggregation, reference, device)
    views, cal = twin
    kw = dict(zmin_m=0.28, zmax_m=1.1, reference=reference, cost=cost, aggregation=aggregation, method="local")
    ref = estimate_depth(views, cal, **kw)
    got = estimate_depth(views, cal, backend="torch", device=device, **kw)
    assert got.depth_m.dtype == np.float32 and got.depth_m.shape == ref.depth_m.shape
    assert got.confidence.dtype == np.float32
    np.testing.assert_array_equal(got.depths_m, ref.depths_m)
    both, depth_ok, conf_ok = _agreement(ref, got)
    assert np.array_equal(np.isfinite(got.depth_m), np.isfinite(ref.depth_m))
    assert both.mean() > 0.5
    assert depth_ok >= 0.99, depth_ok
    assert conf_ok >= 0.99, conf_ok


def _halves_parity(twin, aggregation, reference, device):
    """'lcn-halves': the torch sweep fills the volume and the halves' volume as the NumPy one."""
    import warnings

    from lfring.depth.costs.lcn import lcn_sources
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.depth.plan import sweep_masks
    from lfring.depth.sweep.slices import sweep_slices
    from lfring.errors import LfringWarning

    views, cal = twin
    h, w = views.shape[1:3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = cal.homographies(depth_hypotheses(cal, 0.28, 1.1), reference=reference)
    masks = sweep_masks(cal, (h, w))
    src = lcn_sources(views, cal, 9)
    guide = np.ascontiguousarray(np.clip(views[0].mean(axis=-1), 0, 1), np.float32) if aggregation == "guided" else None
    n = len(hs)
    want_v, want_h, got_v, got_h = (np.empty((n, h, w), np.float32) for _ in range(4))
    filt = None if guide is None else cv2.ximgproc.createGuidedFilter(guide, 5 // 2, 1e-3)
    sweep_slices(src, masks, hs, "lcn-halves", 9, filt, 1, 5, volume=want_v, halves=want_h)
    slices.sweep_slices_torch(src, masks, hs, cost="lcn-halves", aggregation=aggregation, window_px=9, aggregate_px=5,
                            guide=guide, device=device, volume=got_v, halves=got_h)
    for got, want in ((got_v, want_v), (got_h, want_h)):
        fin = np.isfinite(want)
        assert np.mean(np.isfinite(got) == fin) > 0.999
        both = fin & np.isfinite(got)
        assert np.mean(np.isclose(got[both], want[both], rtol=1e-3, atol=1e-4)) > 0.995
    assert np.isfinite(want_h).mean() > 0.3


@pytest.mark.parametrize("reference", [0, "center"])
def test_parity_of_the_semi_global_default(twin, reference, device):
    """The default 'sgm' method with the torch backend: its cost volume and optimisation in
    torch, the same depth as the float32 NumPy/numba reference of the method nearly everywhere
    (the 16-bit fused passes are held to that reference in test_semiglobal.py)."""
    views, cal = twin
    kw = dict(zmin_m=0.28, zmax_m=1.1, reference=reference)
    ref = estimate_depth(views, cal, method="sgm-reference", **kw)
    got = estimate_depth(views, cal, backend="torch", device=device, **kw)
    assert ref.method == "sgm-reference" and got.method == "sgm"
    both, depth_ok, conf_ok = _agreement(ref, got)
    assert both.mean() > 0.5
    assert depth_ok >= 0.97, depth_ok
    assert conf_ok >= 0.95, conf_ok


def test_parity_over_many_chunks(twin, monkeypatch, device):
    """Chunks of three hypotheses: the streamed bookkeeping carries over chunk boundaries."""
    views, cal = twin
    h, w = views.shape[1:3]
    monkeypatch.setattr(slices, "_CHUNK_BYTES", 3 * slices._IMAGES_PER_HYPOTHESIS * 4 * h * w * 4)
    assert slices._chunk_size(16, 4, h, w) == 3
    kw = dict(zmin_m=0.28, zmax_m=1.1, num_planes=16, reference=1, cost="zncc", aggregation="guided", method="local")
    ref = estimate_depth(views, cal, **kw)
    got = estimate_depth(views, cal, backend="torch", device=device, **kw)
    _, depth_ok, conf_ok = _agreement(ref, got)
    assert depth_ok >= 0.99 and conf_ok >= 0.99


def _brute_force(aggs, exclude):
    """What the streamed trackers must give, from the whole cost volume."""
    n = len(aggs)
    best_i = np.argmin(aggs, axis=0)  # the first of equal minima
    take = lambda j: np.take_along_axis(aggs, np.clip(j, 0, n - 1)[None], axis=0)[0]
    best = take(best_i)
    c_prev = np.where(best_i > 0, take(best_i - 1), np.inf)
    c_next = np.where(best_i < n - 1, take(best_i + 1), np.inf)
    far = np.abs(np.arange(n)[:, None, None] - best_i[None]) > exclude
    second = np.where(far, aggs, np.inf).min(axis=0)
    return {"best": best, "best_i": best_i, "c_prev": c_prev, "c_next": c_next, "second": second}


@pytest.mark.parametrize("exclude", [1, 2, 3])
def test_running_minimum_is_exact(exclude, device):
    """Integer costs with ties, gaps and missing (inf) slices: the NumPy/OpenCV tracker and the
    torch one, fed in chunks of any size, give exactly the minimum, its first index, its
    neighbours and the lowest cost more than ``exclude`` hypotheses away from it."""
    rng = np.random.default_rng(exclude)
    h, w = 5, 7
    for trial in range(40):
        n = int(rng.integers(1, 25))
        aggs = rng.integers(0, 5, (n, h, w)).astype(np.float32)
        aggs[rng.random(aggs.shape) < 0.2] = np.inf
        want = _brute_force(aggs, exclude)
        run = RunningMinimum((h, w), exclude)
        for i in range(n):
            np.copyto(run.slot(), aggs[i])
            run.push()
        got = {"best": run.best, "best_i": run.best_i, "c_prev": run.c_prev, "c_next": run.c_next, "second": run.second()}
        trun = RunningMinimumTorch(torch, (h, w), exclude, device)
        i = 0
        while i < n:
            c = min(int(rng.integers(1, 8)), n - i)
            trun.push_chunk(torch.from_numpy(aggs[i:i + c]).to(device))
            i += c
        tgot = {"best": trun.best, "best_i": trun.best_i, "c_prev": trun.c_prev, "c_next": trun.c_next, "second": trun.second()}
        for name in want:
            np.testing.assert_array_equal(got[name], want[name], err_msg=f"numpy {name}, trial {trial}")
            np.testing.assert_array_equal(tgot[name].cpu().numpy(), want[name], err_msg=f"torch {name}, trial {trial}")


@pytest.mark.parametrize("shape, k", [((37, 53), 9), ((53, 37), 5), ((4, 9), 9), ((1, 6), 3), ((20, 30), 1)])
def test_windows_match_opencv(shape, k, device):
    """Box windows as cv2.boxFilter (BORDER_REFLECT_101); the guided filter as ximgproc's
    (radius k // 2, BORDER_REFLECT, eps on the guide's variance), including windows wider than the image."""
    rng = np.random.default_rng(7)
    x = (rng.random(shape) * 3).astype(np.float32)
    g = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2)
    g = ((g - g.min()) / max(float(g.max() - g.min()), 1e-6)).astype(np.float32)
    box = BoxTorch(torch, shape, k, 1, device)(torch.from_numpy(x)[None, None].to(device))[0, 0].cpu().numpy()
    np.testing.assert_allclose(box, cv2.boxFilter(x, -1, (k, k)), atol=1e-6)
    guided = GuidedTorch(torch, g, k, 1e-3, device)(torch, torch.from_numpy(x)[None].to(device))[0].cpu().numpy()
    np.testing.assert_allclose(guided, cv2.ximgproc.createGuidedFilter(g, k // 2, 1e-3).filter(x), atol=1e-4)


def test_errors(twin, device):
    views, _ = twin
    v, h, w = views.shape[:3]
    lum = np.ones((v, h, w), np.float32)
    hs = np.tile(np.eye(3), (2, v, 1, 1))
    kw = dict(cost="sad", aggregation="guided", window_px=9, device=device)
    with pytest.raises(InvalidInputError, match="guide image"):
        slices.sweep_slices_torch(lum, lum, hs, guide=None, **kw)
    with pytest.raises(InvalidInputError, match="float32"):
        slices.sweep_slices_torch(lum.astype(np.float64), lum, hs, guide=lum[0], **kw)
    with pytest.raises(InvalidInputError, match="homographies"):
        slices.sweep_slices_torch(lum, lum, hs[:, :2], guide=lum[0], **kw)
