"""Inspection at a working plane on rendered parts of the twin (2 x 2 binned, realistic noise,
the shipped calibration): every planted bump and dent is found with its sign and size, good parts
pass, and bad inputs are refused with the bad value named (lfring.inspect.measure)."""

import numpy as np
import pytest

from inspect_parts import DATA, PLANE, TOL, overlap, truth_deviation, views_of
from lfring.calibration.defaults import default_calibration
from lfring.errors import InvalidInputError, LfringError, LfringWarning
from lfring.inspect import Defect, InspectionResult, default_depth_band, inspect_frame
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.synth import render
from lfring.synth.presets import part_scene
from lfring.views import split_views


def test_edge_of_two_views_coverage_makes_no_false_defect(prototype):
    """A good part (seed 100 of benchmarks/bench_inspect.py) whose belt, 10 cm behind the plane,
    meets the edge of what two views see near the bottom of the frame: there the sweep's window
    averaged its few seen pixels into a confident false 55 mm dent, until only pixels whose whole
    window two views see are checked."""
    cal = default_calibration((2456, 1842))[0]
    r = render(prototype, part_scene(defect_heights_m=(), depth_m=PLANE, seed=100), binning=2, noise="realistic", seed=100)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    res = inspect_frame(split_views(demosaic(frame), cal.layout), cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
    assert res.verdict == "pass" and res.defects == () and res.coverage > 0.95


def test_good_part_passes(parts):
    r, cal, views, truth, res = parts["good"]
    assert truth == []
    assert isinstance(res, InspectionResult) and res.passed and res.defects == ()
    assert res.deviating.sum() == 0
    # Good parts sit on the plane: the reliable deviations are small and unbiased.
    assert abs(res.stats["median_abs_deviation_m"]) < 0.002
    assert res.stats["reliable_fraction"] > 0.4


@pytest.mark.parametrize("name", ["two", "three"])
def test_every_planted_defect_is_found(parts, name):
    r, cal, views, truth, res = parts[name]
    assert len(truth) == len(r.scene.surfaces[0].bumps)
    assert not res.passed and len(res.defects) == len(truth)  # no false defect either
    for box, dev in truth:
        hits = [d for d in res.defects if overlap(d.bbox_px, box)]
        assert len(hits) == 1, (box, res.defects)
        d = hits[0]
        assert np.sign(d.deviation_m) == np.sign(dev) and d.kind == ("bump" if dev > 0 else "dent")
        assert abs(d.deviation_m - dev) < 0.003, (d.deviation_m, dev)  # within 3 mm of the truth
        assert 0.8 < d.mean_confidence <= 1.0 and not d.beyond_band
        # The box lies inside the truth's footprint (> tol/2) give or take the depth's smoothing.
        x, y, w, h = d.bbox_px
        assert box[0] - 4 <= x and x + w <= box[0] + box[2] + 4 and box[1] - 4 <= y and y + h <= box[1] + box[3] + 4


def test_result_maps_and_areas(parts):
    r, cal, views, truth, res = parts["two"]
    shape = views.shape[1:3]
    for m in (res.plane_mask, res.reliable, res.deviating):
        assert m.dtype == bool and m.shape == shape
    assert res.deviation_m.dtype == np.float32 and res.refocused.shape == (*shape, 3)
    assert res.settings["zmin_m"] < PLANE < res.settings["zmax_m"]
    # The plane is one of the hypotheses (a good part sits on one, not between two).
    assert np.min(np.abs(res.depth.depths_m - PLANE)) < 1e-9
    # A binned pixel covers about 0.14 mm at 0.3 m (the 80 mm part spans about 580 px); areas follow.
    for d in res.defects:
        assert isinstance(d, Defect)
        assert d.area_mm2 == pytest.approx(d.area_px * res.settings["pixel_footprint_mm"] ** 2)
    assert 0.12 < res.settings["pixel_footprint_mm"] < 0.16
    # The working plane: mostly photo-consistent on the part, never on the belt 10 cm behind.
    dev = truth_deviation(r, cal, PLANE)
    flat = np.abs(dev) < 1e-4
    belt = dev < -0.05
    assert res.plane_mask[flat].mean() > 0.6 and res.plane_mask[belt].mean() < 0.05


def test_roi_and_reference_depth(parts):
    r, cal, views, truth, res = parts["two"]
    d = res.defects[0]
    x, y, w, h = d.bbox_px
    inside = (max(x - 20, 0), max(y - 20, 0), w + 40, h + 40)
    only = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, roi=inside)
    assert len(only.defects) == 1 and only.defects[0].kind == d.kind and only.settings["roi_px"] == list(inside)
    assert only.reliable[: inside[1]].sum() == 0  # nothing outside the ROI can raise an alarm
    # Against its own depth map (a golden part with the same bumps) the part passes.
    known = np.where(res.reliable, res.depth.depth_m, np.nan).astype(np.float32)  # NaN where unknown
    golden = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, reference_depth_m=known)
    assert golden.passed and golden.settings["reference_depth"] is True
    # The golden part's DepthResult itself: its measured depths; in another frame, refused.
    with pytest.warns(LfringWarning, match="tolerance_m"):  # the map reaches the belt, where 8 mm is little motion
        golden = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, reference_depth_m=res.depth)
    assert golden.passed and golden.settings["reference_depth"] is True
    with pytest.raises(InvalidInputError, match="in the frame of reference 'center', the inspection in 0"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, reference_depth_m=res.depth, reference=0)
    # Without device=, areas come from the device the calibration names (binned to its frames).
    assert cal.device == "prototype" and only.defects[0].area_mm2 is not None
    explicit = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, roi=inside, device=r.device)
    assert only.defects[0].area_mm2 == pytest.approx(explicit.defects[0].area_mm2)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(tolerance_m=0.0), "tolerance_m must be a positive"),
        (dict(tolerance_m=-0.01), "tolerance_m must be a positive"),
        (dict(tolerance_m=float("nan")), "tolerance_m must be a positive"),
        (dict(tolerance_m=float("inf")), "tolerance_m"),
        (dict(tolerance_m=True), "tolerance_m"),
        (dict(plane_m=float("nan")), "plane_m"),
        (dict(plane_m=0.01), "depth origin"),
        (dict(roi=(600, 600, 200, 200)), r"roi \(x=600, y=600, w=200, h=200\) does not fit"),
        (dict(roi=(0, 0, 10)), "four integers"),
        (dict(roi=(0, 0, 0, 10)), "at least 1 px"),
        (dict(roi=(-1, 0, 10, 10)), "does not fit"),
        (dict(roi=(0.5, 0, 10, 10)), "four integers"),
        (dict(reference_depth_m=np.full((10, 10), 0.3, np.float32)), r"shape \(h, w\) = \(705, 705\), got \(10, 10\)"),
        (dict(reference_depth_m=np.full((705, 705), 0.001, np.float32)), "metres, not mm"),
        (dict(reference_depth_m=np.full((705, 705), np.nan, np.float32)), "no finite depth"),
        (dict(reference_depth_m=np.full((705, 705), 3, np.int32)), "float map"),
        (dict(min_area_px=0), "min_area_px"),
        (dict(min_confidence=1.5), "min_confidence"),
        (dict(percentile=0), "percentile"),
        (dict(zmin_m=0.31, zmax_m=0.4), "must contain the plane"),
        (dict(zmin_m=0.25, zmax_m=0.29), "must contain the plane"),
        (dict(num_planes=2), "num_planes"),
        (dict(reference="left"), "reference"),
        (dict(opening_px=-1), "opening_px"),
        (dict(num_planes=10**7), "give at most"),
        (dict(opening_px=5000), r"opening_px must be an integer >= 0 and <= 705"),
        # Larger than the views: it said "no surface found at the working plane".
        (dict(min_area_px=600000), r"min_area_px must be an integer >= 1 and <= 497025 \(a defect's least area"),
    ],
)
def test_bad_inputs(parts, kwargs, match):
    r, cal, views, *_ = parts["good"]
    args = dict(plane_m=PLANE, tolerance_m=TOL) | kwargs
    with pytest.raises(InvalidInputError, match=match):
        inspect_frame(views, cal, **args)


def test_a_plane_so_far_that_the_views_do_not_move_is_refused(parts):
    """A plane at 1e20 m (a ZeroDivisionError before): refused as no depth can be told there."""
    r, cal, views, *_ = parts["good"]
    with pytest.warns(LfringWarning, match="outside the calibrated range"):
        with pytest.raises(InvalidInputError, match=r"the views do not move at all between depths around 1e\+20 m"):
            inspect_frame(views, cal, plane_m=1e20, tolerance_m=TOL)


def test_bad_views_and_device(parts, prototype):
    r, cal, views, *_ = parts["good"]
    with pytest.raises(InvalidInputError, match="float32"):
        inspect_frame(views.astype(np.float64), cal, plane_m=PLANE, tolerance_m=TOL)
    with pytest.raises(InvalidInputError, match="layout cuts"):
        inspect_frame(views[:, :-1], cal, plane_m=PLANE, tolerance_m=TOL)
    with pytest.raises(InvalidInputError, match="bin it"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=prototype)


def test_reference_depth_in_millimetres(parts):
    r, cal, views, *_ = parts["good"]
    mm = np.full(views.shape[1:3], 300.0, np.float32)
    with pytest.warns(LfringWarning, match="outside the calibrated range"):
        with pytest.raises(InvalidInputError, match="reference_depth_m holds depths of 300 m: .*reaches infinity.*mm"):
            inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, reference_depth_m=mm)


@pytest.mark.parametrize("args, match", [
    # A tolerance in mm, or one whose band passes infinity: the tolerance is named, not the plane.
    (dict(tolerance_m=10.0), r"tolerance_m \(10 m\) must be smaller than the plane's distance .*given in mm"),
    (dict(tolerance_m=0.1), "tolerance_m 0.1 m is too large for a surface at 0.3 m"),
    (dict(tolerance_m=TOL, zmin_m=0.4, zmax_m=0.2), r"zmin_m \(0.4\) must be smaller than zmax_m \(0.2\)"),
])
def test_band_refusals_name_the_cause(parts, args, match):
    r, cal, views, *_ = parts["good"]
    with pytest.raises(InvalidInputError, match=match):
        inspect_frame(views, cal, plane_m=PLANE, **args)


def test_band_reaching_infinity_says_why(prototype):
    """A plane the views cannot tell from infinity is refused with the motion in pixels; the
    refusal suggests millimetres only where the number, read as mm, is a depth the calibration
    covers (a coarse camera at 1 m is not a unit mistake)."""
    from lfring.calibration import RingCalibration

    fine, coarse = (RingCalibration.from_optics(prototype.binned(b)) for b in (1, 4))
    lo, hi = default_depth_band(fine, 1.0, 1.0, 0.005)
    assert lo < 1.0 < hi
    with pytest.raises(InvalidInputError, match="reaches infinity") as err:
        default_depth_band(coarse, 1.0, 1.0, 0.005)
    assert "cannot judge a surface that far" in str(err.value) and "mm" not in str(err.value)
    assert "the views move 1.6 px between 1 m and infinity" in str(err.value)
    for cal in (fine, coarse):
        with pytest.raises(InvalidInputError, match="was 300 given in mm"):
            default_depth_band(cal, 300.0, 300.0, 0.005)


def test_plane_outside_calibrated_range_warns(parts):
    r, cal, views, *_ = parts["good"]
    lo, hi = cal.valid_depth_range_m
    with pytest.warns(LfringWarning, match="outside the calibrated range"), \
            pytest.warns(LfringWarning, match="0.11 px of view motion at 1.2 m"):
        inspect_frame(views, cal, plane_m=hi + 0.2, tolerance_m=0.05, min_area_px=400)


# -- verdicts and coverage: nothing passes that was not checked -----------------------------------
def test_good_part_is_checked_and_passes(parts):
    r, cal, views, truth, res = parts["good"]
    assert res.verdict == "pass" and res.passed and res.reason is None
    assert 0.95 <= res.coverage < 1.0 and res.stats["coverage"] == res.coverage
    # The part is found from evidence that does not need confident depth: it is the true part
    # (the plate within 5 cm of the plane) wherever two views or more see it, and not the belt.
    dev = truth_deviation(r, cal, PLANE)
    plate, belt = np.abs(np.nan_to_num(dev, nan=1.0)) < 0.05, np.nan_to_num(dev) < -0.05
    seen = np.isfinite(res.depth.depth_m)
    assert res.part[plate & seen].mean() > 0.97 and res.part[belt].mean() < 0.02
    # Coverage is the checked share of that part, which holds unchecked pixels too.
    assert res.coverage == pytest.approx((res.reliable & res.part).sum() / res.part.sum())
    assert (res.part & ~res.reliable).sum() > 500
    # Of the true plate, only the corners that a single view sees (about 9 %) stay unchecked.
    assert (res.reliable & plate).sum() / plate.sum() > 0.85


def test_defective_part_fails_with_its_coverage(parts):
    res = parts["two"][4]
    assert res.verdict == "fail" and not res.passed and res.reason is None and len(res.defects) == 2
    assert 0.8 <= res.coverage <= 1.0


def test_wrong_plane_cannot_be_judged(parts):
    r, cal, views, truth, _ = parts["two"]
    with pytest.warns(LfringWarning, match="px of view motion at 0.5 m"):
        res = inspect_frame(views, cal, plane_m=0.5, tolerance_m=TOL)
    assert res.verdict == "cannot_judge" and not res.passed
    assert res.reason.startswith("no surface found at the working plane")
    # Only specks of the belt 10 cm nearer (in the band at 0.5 m, where a pixel of disparity is
    # 67 mm) lie near the plane: too little to be a part.
    assert res.stats["part_fraction"] < 0.02 and res.defects == () and not res.deviating.any()
    assert res.coverage == 0.0 and res.stats["coverage"] == 0.0  # no part found: none of it checked


@pytest.mark.parametrize("level", [0.0, 0.003])
def test_lens_cap_cannot_be_judged(parts, level):
    r, cal, views, *_ = parts["good"]
    rng = np.random.default_rng(5)
    dark = np.clip(level + 0.001 * rng.standard_normal(views.shape), 0, 1).astype(np.float32) if level else np.zeros_like(views)
    res = inspect_frame(dark, cal, plane_m=PLANE, tolerance_m=TOL)
    assert res.verdict == "cannot_judge" and res.reason.startswith("frame too dark") and res.defects == ()
    assert res.coverage == 0.0 and res.stats["luminance_p99"] < 0.01


def test_flat_frame_cannot_be_judged():
    views, cal = views_of(DATA / "flat.png")
    res = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL)
    assert res.verdict == "cannot_judge" and res.reason.startswith("frame too flat") and res.defects == ()
    assert res.stats["textured_fraction"] < 0.02


def test_unrelated_photo_cannot_be_judged():
    """An ordinary picture at the sensor's size (no ring behind it): its four 'views' are
    different parts of one image, consistent at no depth."""
    from lfring.synth.textures import Texture, rasterize

    cal = default_calibration((2456, 1842))[0]
    image = np.ascontiguousarray(rasterize(Texture("image", name="coffee"), (2456, 1842), 1.0))
    assert image.shape == (1842, 2456, 3)
    res = inspect_frame(split_views(image, cal.layout), cal, plane_m=PLANE, tolerance_m=TOL)
    assert res.verdict == "cannot_judge" and res.reason.startswith("no surface found at the working plane")
    assert res.stats["textured_fraction"] > 0.5 and res.stats["part_fraction"] < 0.02


def test_min_coverage_decides_between_pass_and_cannot_judge(parts):
    r, cal, views, truth, res = parts["good"]
    strict = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, min_coverage=0.99)
    assert strict.verdict == "cannot_judge" and strict.reason.startswith("too few confident pixels")
    assert f"checked {res.coverage:.1%} of the part" in strict.reason and strict.coverage == pytest.approx(res.coverage)
    assert strict.settings["min_coverage"] == 0.99 and res.settings["min_coverage"] == 0.8
    # A part inside an ROI that only the four views see is checked almost entirely.
    inner = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, roi=(200, 200, 300, 300), min_coverage=0.95)
    assert inner.verdict == "pass" and inner.coverage > 0.95
    assert not inner.part[:200].any() and inner.part[250:450, 250:450].all()
    with pytest.raises(InvalidInputError, match=r"min_coverage must be a number in \[0, 1\], got 1.5"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, min_coverage=1.5)


def test_a_defect_beyond_the_band_is_a_lower_bound(prototype):
    """A 120 mm bump, 30 mm across, on a part at 0.3 m: the default band reaches about 55 mm
    nearer, so the bump's top was out of band and the defect read +44 mm, as if measured. It is
    found and marked beyond the band (its deviation a lower bound); a band that holds it measures it."""
    cal = default_calibration((2456, 1842))[0]
    r = render(prototype, part_scene(defect_heights_m=(0.12,), defect_size_m=0.03, depth_m=PLANE, seed=2), binning=2,
               noise="realistic", seed=2)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), cal.layout)
    res = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
    assert res.verdict == "fail" and len(res.defects) == 1
    d = res.defects[0]
    assert d.kind == "bump" and d.beyond_band and 0.02 < d.deviation_m < 0.08
    assert d.to_dict()["beyond_band"] is True
    wide = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=r.device, zmin_m=0.16)
    assert len(wide.defects) == 1 and not wide.defects[0].beyond_band
    assert abs(wide.defects[0].deviation_m - 0.12) < 0.015


def test_a_tolerance_below_the_depth_noise_is_warned_of(parts):
    """A flat target on its own plane at 0.5 m judged to 8 mm (0.11 px of view motion) failed
    with 21 false defects at the views' rims, without a word; 8 mm at 0.3 m is 0.34 px."""
    r, cal, views, truth, res = parts["good"]
    with pytest.warns(LfringWarning, match=r"tolerance_m 0.002 m is 0.084 px of view motion at 0.3 m, below 0.25 px"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=0.002)


def test_a_part_off_the_plane_is_said_to_lie_beyond_the_band(parts):
    """A good part at 0.3 m checked at 0.4 m: 'too few confident pixels ... the rest is
    untextured, occluded, ...' sent the operator to the texture and the lighting, though the
    frame is textured and the part lies 10 cm off the plane. The reason now says how much lies
    beyond the band searched and asks whether the part is at the plane."""
    r, cal, views, truth, _ = parts["good"]
    with pytest.warns(LfringWarning, match="px of view motion at 0.4 m"):
        res = inspect_frame(views, cal, plane_m=0.4, tolerance_m=TOL)
    assert res.verdict == "cannot_judge" and res.reason.startswith("too few confident pixels")
    assert res.stats["textured_fraction"] > 0.9 and res.stats["beyond_band_fraction"] > 0.5
    assert f"{res.stats['beyond_band_fraction']:.0%} of the frame lies beyond the depth band" in res.reason
    assert "is the part at the working plane" in res.reason


def test_a_part_beyond_the_views_common_sight_is_told_and_hatched(prototype):
    """A part larger than what two views see, a 15 mm bump in its corner where one view alone
    sees it: the inspection cannot check it, and said 'pass (checked 97 % of the part)' with the
    corners neither part nor hatched. The part's possible continuation beyond that rim is now
    given (``beyond_sight``, its share in the stats) and hatched; it holds the bump."""
    from lfring.inspect.draw import annotate
    from lfring.synth import Bump, HeightField, Plane, Scene, Texture

    bump = Bump(center_m=(0.008, 0.008), size_m=(0.012, 0.012), height_m=0.015, shape="dome")
    part = HeightField(PLANE, (0.08, 0.08), Texture("image", name="gravel"), bumps=(bump,), name="part")
    belt = Plane(0.4, (0.5, 0.5), Texture("speckle", feature_m=0.003, seed=1,
                                          colors=((0.02, 0.02, 0.03), (0.25, 0.25, 0.3))), name="belt")
    r = render(prototype, Scene((part, belt)), binning=2, noise="realistic", seed=4)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    cal = default_calibration((2456, 1842))[0]
    res = inspect_frame(split_views(demosaic(frame), cal.layout), cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
    truth = truth_deviation(r, cal, PLANE)
    raised = np.nan_to_num(truth) > TOL  # the bump, as the views' truth maps it
    assert raised.sum() > 100 and not (res.reliable & raised).any()  # never checked
    assert res.beyond_sight[raised].mean() > 0.9 and not (res.beyond_sight & res.part).any()
    assert res.unchecked[raised].all()
    share = res.beyond_sight.sum() / res.part.sum()
    assert res.stats["beyond_sight_fraction"] == pytest.approx(share) and 0.1 < share < 0.4
    image = annotate(res)
    assert image.shape[:2] == res.part.shape


def test_a_device_by_name_is_binned_to_the_frames(parts):
    """device='prototype' (as to_points takes it) raised AttributeError on a str; it is the
    built-in device binned to the calibration's frames, and anything else is refused clearly."""
    from lfring.depth.io import device_for

    r, cal, views, truth, res = parts["two"]
    named = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device="prototype")
    given = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=device_for(cal, "prototype"))
    assert [d.area_mm2 for d in named.defects] == [d.area_mm2 for d in given.defects]
    assert named.defects and all(d.area_mm2 > 0 for d in named.defects)
    with pytest.raises(InvalidInputError, match="a device is a RingDevice, a built-in name"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=3)
    with pytest.raises(LfringError, match="no built-in device named 'nope'"):
        inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device="nope")
