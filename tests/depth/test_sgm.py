"""Semi-global aggregation, selection and confidence against constructions with known disparity."""

import numpy as np
import pytest
from sgm_scenes import FAR_INDEX, NEAR_INDEX, reference_sgm, scene

from lfring.depth.sgm import (
    combine_confidence,
    cost_scale,
    select,
    sgm_aggregate,
    sparsification_auc,
)
from lfring.errors import InvalidInputError

P1, P2 = 0.1, 1.0  # the scenes' cost rises by 1 per hypothesis near the truth, noise 0.05


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("edge_scale", [None, 0.05])
def test_kernel_equals_brute_force_recursion(paths, edge_scale):
    rng = np.random.default_rng(3)
    cost = rng.random((6, 7, 9)).astype(np.float32)
    cost[2, 3, 4] = np.nan  # invalid entries: replaced by the pixel's mean finite cost
    cost[:, 5, 1] = np.inf  # a pixel with no finite cost at all
    guide = rng.random((7, 9)).astype(np.float32)
    got = sgm_aggregate(cost, guide=guide, p1=0.07, p2=0.4, paths=paths, edge_scale=edge_scale)
    want = reference_sgm(cost, guide=guide, p1=0.07, p2=0.4, paths=paths, edge_scale=edge_scale)
    assert got.dtype == np.float32 and got.shape == cost.shape
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_threads_do_not_change_the_result():
    cost = np.random.default_rng(4).random((9, 40, 150)).astype(np.float32)
    one = sgm_aggregate(cost, p1=0.05, p2=0.3, paths=8, threads=1)
    two = sgm_aggregate(cost, p1=0.05, p2=0.3, paths=8, threads=2)
    np.testing.assert_array_equal(one, two)


def test_sgm_recovers_the_textureless_band():
    s = scene(seed=0)
    wta = s.cost.argmin(axis=0)
    assert np.mean(np.abs(wta - s.truth)[s.flat] > 2) > 0.5  # raw winner-take-all: mostly wrong
    index, _ = select(sgm_aggregate(s.cost, guide=s.guide, p1=P1, p2=P2))
    err = np.abs(index - s.truth)
    assert np.mean(err[s.flat] <= 2) > 0.95  # within 2 hypotheses in 95 % of the band
    assert np.median(err[s.flat]) <= 1.0
    assert np.mean(err[~s.flat] <= 0.5) > 0.99  # and textured pixels stay right


@pytest.mark.parametrize("use_raw", [False, True])
def test_subpixel_recovers_the_slanted_plane(use_raw):
    s = scene(seed=1)
    agg = sgm_aggregate(s.cost, guide=s.guide, p1=P1, p2=P2)
    index, _ = select(agg, raw=s.cost if use_raw else None)
    inner = s.slant.copy()
    inner[:, :2] = inner[:, -2:] = False
    inner[-2:] = False
    rms = np.sqrt(np.mean((index - s.truth)[inner] ** 2))
    assert rms < 0.1
    integer_rms = np.sqrt(np.mean((np.round(index) - s.truth)[inner] ** 2))
    assert rms < 0.5 * integer_rms  # the fraction is recovered, not just the nearest integer


def _wrong_surface_per_row(index, truth, rows):
    wrong = np.abs(index - truth) > 0.5 * (NEAR_INDEX - FAR_INDEX)
    return wrong[rows].sum(axis=1)


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_edge_aware_penalty_keeps_the_step_edge_at_the_guide_edge(seed, paths):
    # Textureless on both sides of the edge, off-centre: only the guide says where the edge is.
    s = scene(seed=seed, flat_band=False, edge_band=True, slanted=False, flat_noise=0.01)
    rows = slice(None)
    guided, _ = select(sgm_aggregate(s.cost, guide=s.guide, p1=P1, p2=P2, paths=paths, edge_scale=0.04))
    blind, _ = select(sgm_aggregate(s.cost, p1=P1, p2=P2, paths=paths))
    band_guided = _wrong_surface_per_row(guided, s.truth, rows)
    band_blind = _wrong_surface_per_row(blind, s.truth, rows)
    assert band_guided.max() <= 2  # the depth edge is within 2 px of the image edge on every row
    assert band_blind.max() > 2 * band_guided.max() + 4  # without the guide it lands elsewhere


def test_confidence_ranks_errors():
    s = scene(seed=2, noise=0.1)
    index, conf = select(sgm_aggregate(s.cost, guide=s.guide, p1=P1, p2=P2))
    sp = sparsification_auc(index - s.truth, conf)
    assert sp.oracle_auc <= sp.auc < sp.random_auc
    assert sp.auc - sp.oracle_auc < sp.random_auc - sp.auc  # closer to the oracle than to random
    assert 0 <= conf.min() and conf.max() <= 1


def test_confidence_combined_with_a_second_estimate_ranks_better():
    s = scene(seed=2, noise=0.1)
    agg = sgm_aggregate(s.cost, guide=s.guide, p1=P1, p2=P2)
    index, conf = select(agg)
    # A second, independent measurement of the same scene (another view pair: other noise).
    other = scene(seed=12, noise=0.1)
    other_index, _ = select(sgm_aggregate(other.cost, guide=other.guide, p1=P1, p2=P2))
    combined = combine_confidence(conf, index, other_index, tolerance=1.0)
    a = sparsification_auc(index - s.truth, conf).auc
    b = sparsification_auc(index - s.truth, combined).auc
    assert b < a
    assert combined.dtype == np.float32 and np.all((combined >= 0) & (combined <= conf + 1e-7))


def test_select_on_a_known_curve():
    cost = np.full((7, 1, 3), 5.0, np.float32)
    cost[:, 0, 0] = [4, 3, 1, 2, 4, 4, 0.5][::-1]  # minimum at 0 (the end), curving down: no offset
    cost[:, 0, 1] = [9, 4, 1, 2, 5, 6, 8]  # minimum at 2, parabola offset (4 - 2) / (2 (4 - 2 + 2))
    cost[:, 0, 2] = np.nan  # nothing known
    index, conf = select(cost, exclude=1)
    assert index[0, 0] == pytest.approx(0.0)
    assert index[0, 1] == pytest.approx(2 + 0.25)
    assert conf[0, 1] == pytest.approx(1 - 1 / 5)  # second best away from 1..3 is 5 at index 4
    assert np.isnan(index[0, 2]) and conf[0, 2] == 0


def test_select_fits_the_parabola_inwards_at_the_range_ends():
    """A minimum within half a hypothesis inside the first or last one comes out where it is,
    from the parabola through the end and the next two costs; one beyond the end stays at the end."""
    i = np.arange(7, dtype=np.float32)[:, None, None]
    vertex = np.array([5.7, 0.2, 5.6, 6.4, -2.0], np.float32)[None, None, :]
    cost = np.broadcast_to((i - vertex) ** 2, (7, 1, 5)).astype(np.float32)
    flat = np.ones_like(cost)  # an optimised curve with the same winner and no sub-hypothesis information
    flat[6, 0, [0, 2, 3]] = 0.0
    flat[0, 0, [1, 4]] = 0.0
    for index in (select(cost)[0], select(flat, cost)[0], select(flat, cost, raw_distinctness=True)[0]):
        np.testing.assert_allclose(index[0], [5.7, 0.2, 5.6, 6.0, 0.0], atol=1e-5)


@pytest.mark.parametrize("exclude", [1, 2])
def test_select_with_the_raw_distinctness_equals_two_selections(exclude):
    """One pass gives the index of ``select(agg, raw)`` and the product of its confidence with
    ``select(raw)``'s, to the bit, with NaN and inf entries in both volumes."""
    rng = np.random.default_rng(5)
    agg = rng.random((9, 13, 17), dtype=np.float32)
    raw = rng.random((9, 13, 17), dtype=np.float32)
    agg[:, 3, 4] = 1.0
    agg[3, 3, 4] = 0.0  # the winner is 3 ...
    raw[2:5, 3, 4] = np.nan  # ... and the parabola's points stand in with the pixel's mean finite cost
    raw[:, 6, 6] = np.inf  # no raw information: no raw distinctness
    agg[:, 7, 7] = np.nan  # nothing known
    agg[4, 8, :] = np.inf
    raw[6, 9, :] = np.nan
    index, conf = select(agg, raw, exclude=exclude, raw_distinctness=True)
    want_index, want_conf = select(agg, raw, exclude=exclude)
    want_conf = want_conf * select(raw, exclude=exclude)[1]
    np.testing.assert_array_equal(index, want_index)
    np.testing.assert_array_equal(conf, want_conf)
    assert conf[6, 6] == 0.0 and np.isnan(index[7, 7]) and conf.dtype == np.float32
    with pytest.raises(InvalidInputError, match="raw_distinctness needs"):
        select(agg, raw_distinctness=True)


def test_sparsification_auc_by_hand():
    err = np.array([[1.0, 3.0], [0.0, 2.0]])
    conf = np.array([[0.9, 0.1], [0.5, 0.2]])  # order: 1, 0, 2, 3
    sp = sparsification_auc(err, conf, steps=4)
    np.testing.assert_allclose(sp.curve, [1.0, 0.5, 1.0, 1.5])
    np.testing.assert_allclose(sp.oracle_curve, [0.0, 0.5, 1.0, 1.5])
    assert sp.auc == pytest.approx(1.0) and sp.oracle_auc == pytest.approx(0.75)
    assert sp.random_auc == pytest.approx(1.5)
    masked = sparsification_auc(err, conf, mask=np.array([[True, False], [True, True]]), steps=1)
    assert masked.auc == pytest.approx(1.0)


def test_default_penalties_follow_the_cost_scale():
    s = scene(seed=0)
    a = select(sgm_aggregate(s.cost, guide=s.guide))[0]
    b = select(sgm_aggregate(10 * s.cost, guide=s.guide))[0]
    np.testing.assert_allclose(a, b, atol=1e-4)
    assert cost_scale(10 * s.cost) == pytest.approx(10 * cost_scale(s.cost), rel=1e-5)


def test_importing_lfring_does_not_import_numba():
    import subprocess
    import sys

    code = "import sys, lfring, lfring.depth, lfring.depth.sgm, lfring.depth.refine; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"cost": np.zeros((4, 5))}, "(N, h, w)"),
        ({"cost": np.zeros((4, 5, 6), np.int32)}, "floating point"),
        ({"cost": np.zeros((0, 5, 6), np.float32)}, "empty"),
        ({"paths": 6}, "paths must be one of"),
        ({"p1": -1.0}, "p1 must be >= 0"),
        ({"p2": float("nan")}, "p2 must be"),
        ({"edge_scale": 0.0, "guide": np.zeros((5, 6))}, "edge_scale must be > 0"),
        ({"guide": np.zeros((6, 5))}, "guide must be an"),
        ({"threads": 0}, "threads must be"),
        ({"threads": True}, "threads must be"),
        ({"paths": 4.0}, "paths must be one of"),
        ({"paths": [4]}, "paths must be one of"),
        ({"p1": "1"}, "p1 must be a number"),
        ({"p1": np.array([1.0, 2.0])}, "p1 must be a number"),
        ({"guide": np.where(np.arange(30).reshape(5, 6) == 7, np.nan, 0.5)}, "finite numeric"),
        ({"guide": np.zeros((5, 6), bool)}, "finite numeric"),
        ({"guide": np.zeros((5, 6, 4))}, "guide must be an"),
    ],
)
def test_sgm_aggregate_rejects_bad_arguments(kwargs, match):
    args = {"cost": np.zeros((4, 5, 6), np.float32), "p1": 0.1, "p2": 1.0}
    args.update(kwargs)
    with pytest.raises(InvalidInputError, match=match.replace("(", r"\(").replace(")", r"\)")):
        sgm_aggregate(args.pop("cost"), **args)


def test_select_and_metrics_reject_bad_arguments():
    with pytest.raises(InvalidInputError, match="raw must have"):
        select(np.zeros((4, 5, 6), np.float32), np.zeros((4, 5, 5), np.float32))
    with pytest.raises(InvalidInputError, match="exclude"):
        select(np.zeros((4, 5, 6), np.float32), exclude=-1)
    for threads in (0, -3, 1.5, True, "a"):
        with pytest.raises(InvalidInputError, match="threads must be"):
            select(np.zeros((4, 5, 6), np.float32), threads=threads)
    with pytest.raises(InvalidInputError, match="one shape"):
        sparsification_auc(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(InvalidInputError, match="no pixel"):
        sparsification_auc(np.full((2, 2), np.nan), np.zeros((2, 2)))
    with pytest.raises(InvalidInputError, match="tolerance"):
        combine_confidence(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), tolerance=0)
