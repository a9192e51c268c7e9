"""lfring.batch.pipeline: the outputs of one frame, as the batch writes them."""

import cv2
import numpy as np
import pytest
from batch_frames import load_calibration, render_frames

from lfring.batch import BatchSettings, process_frame, run_batch


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


def test_depth_and_all_in_focus_outputs(frames, tmp_path):
    import tifffile

    d, cal_path = frames
    out = tmp_path / "out"
    settings = BatchSettings(depth=True, zmin_m=0.25, zmax_m=1.2, all_in_focus=True, calibration=load_calibration(cal_path),
                             reference=0)
    res = process_frame(str(d / "scene.png"), settings, settings.outputs("scene"))
    assert res.ok, res.error
    assert set(res.files) == {"depth", "confidence", "depth_preview", "all_in_focus"}
    rep = run_batch([str(d / "scene.png")], out, settings, workers=1)
    assert rep.exit_code == 0
    depth = tifffile.imread(out / "scene_depth.tiff")
    conf = tifffile.imread(out / "scene_confidence.tiff")
    assert depth.dtype == np.float32 and depth.shape == conf.shape
    # The batch writes exactly what estimate_depth gives (its accuracy is tested in tests/depth).
    from lfring import demosaic, estimate_depth, load_raw, split_views

    cal = load_calibration(cal_path)
    direct = estimate_depth(split_views(demosaic(load_raw(d / "scene.png")), cal.layout), cal, zmin_m=0.25, zmax_m=1.2,
                            reference=0)
    np.testing.assert_array_equal(depth, direct.depth_m)
    np.testing.assert_array_equal(conf, direct.confidence)
    # And it is in view 0's frame: on the cup (0.3 m) the confident estimates are within 0.3 px of
    # disparity of the ground truth (about 15 mm at this 4 x 4 binning).
    truth = tifffile.imread(d / "scene_truth" / "depth_view0.tiff")
    cup = np.isfinite(depth) & (conf > 0.5) & (np.abs(truth - 0.3) < 0.005)
    assert cup.sum() > 5000
    assert np.median(np.abs(depth[cup] - truth[cup])) < 0.015
    assert cv2.imread(str(out / "scene_all_in_focus.png")).shape[:2] == depth.shape


def test_ctrl_c_raised_as_another_error_stops_the_run_instead_of_failing_the_frame(frames, monkeypatch):
    """Python 3.10 and 3.11 turn a Ctrl-C that comes while an import builds a class into a
    RuntimeError raised from it: the frame raises the KeyboardInterrupt (the run stops as for
    Ctrl-C) and is not recorded as failed; any other error is still the frame's failure."""
    import lfring.io.levels

    d, cal_path = frames
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=load_calibration(cal_path))
    stop = KeyboardInterrupt()

    def stopped(*args, **kwargs):
        raise RuntimeError("Error calling __set_name__") from stop

    monkeypatch.setattr(lfring.io.levels, "load_frame", stopped)
    with pytest.raises(KeyboardInterrupt) as info:
        process_frame(str(d / "scene.png"), settings)
    assert info.value is stop

    def broken(*args, **kwargs):
        raise RuntimeError("a bug") from ValueError("its cause")

    monkeypatch.setattr(lfring.io.levels, "load_frame", broken)
    res = process_frame(str(d / "scene.png"), settings)
    assert not res.ok and "a bug" in res.error


def test_ctrl_c_that_a_library_turned_into_its_own_error_stops_the_run(frames, monkeypatch):
    """A library that catches every exception can turn a Ctrl-C into an error of its own and
    forget it (matplotlib's image resampling reports an invalid matrix): after a signal's handler
    raised the stop, the frame's error is the stop's, and the frame is not recorded as failed."""
    import lfring.io.levels
    from lfring.core.signals import raise_stop, redelivered_stops

    d, cal_path = frames
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=load_calibration(cal_path))

    def forgets_a_stop(*args, **kwargs):
        try:
            raise_stop(KeyboardInterrupt)  # as a handler does when Ctrl-C comes
        except KeyboardInterrupt:
            pass
        raise ValueError("Invalid affine transformation matrix")

    monkeypatch.setattr(lfring.io.levels, "load_frame", forgets_a_stop)
    with redelivered_stops(), pytest.raises(KeyboardInterrupt):
        process_frame(str(d / "scene.png"), settings)
    # Once the command is over, the same error is the frame's own.
    res = process_frame(str(d / "scene.png"), settings)
    assert not res.ok and "Invalid affine transformation matrix" in res.error


def test_the_viewer_keeps_its_own_depth_map_when_the_all_in_focus_image_takes_the_refocusing_one(frames):
    """Without --depth the viewer estimates its semi-global map, whatever the batch's depth
    method; the all-in-focus image asked for beside it takes the map the refocused images render
    from (here the local method's), and must not hand that one to the viewer."""
    d, cal_path = frames
    common = dict(refocus_m=(0.5,), viewer=True, depth_method="local", calibration=load_calibration(cal_path))
    pages = []
    for aif in (False, True):
        settings = BatchSettings(all_in_focus=aif, **common)
        res = process_frame(str(d / "scene.png"), settings, settings.outputs("scene"))
        assert res.ok, res.error
        pages.append(res.files["viewer"])
    assert pages[0] == pages[1]


def test_a_viewer_left_to_make_takes_the_batchs_own_depth_map(frames):
    """With --depth the viewer shows the batch's own map (here the local method's): also on a
    rerun where the viewer is the only output left to make."""
    d, cal_path = frames
    settings = BatchSettings(depth=True, viewer=True, depth_method="local", calibration=load_calibration(cal_path))
    outputs = settings.outputs("scene")
    pages = [process_frame(str(d / "scene.png"), settings, kinds).files["viewer"]
             for kinds in (outputs, {"viewer": outputs["viewer"]})]
    assert pages[0] == pages[1]


def test_refocused_images_and_the_all_in_focus_image_share_one_renderer(frames, renderers_made):
    """Depth-aware refocusing and the all-in-focus image render from the frame's one depth map:
    its renderer (the all-in-focus colour, the background) is prepared once for both, and each
    image is what the library gives from that map."""
    from lfring import all_in_focus, demosaic, estimate_depth, load_raw, refocus, split_views
    from lfring.io.writers import encode_image

    d, cal_path = frames
    cal = load_calibration(cal_path)
    settings = BatchSettings(refocus_m=(0.4, 0.6), all_in_focus=True, zmin_m=0.25, zmax_m=1.2, calibration=cal)
    res = process_frame(str(d / "scene.png"), settings)
    assert res.ok, res.error
    assert len(renderers_made) == 1
    views = split_views(demosaic(load_raw(d / "scene.png")), cal.layout)
    est = estimate_depth(views, cal, zmin_m=0.25, zmax_m=1.2)
    expected = {"all_in_focus": all_in_focus(views, cal, depth_map_m=est)[0],
                **{f"refocus_{z:g}m": refocus(views, cal, z, method="depth-aware", depth=est) for z in (0.4, 0.6)}}
    for kind, img in expected.items():
        got = cv2.imdecode(np.frombuffer(res.files[kind], np.uint8), cv2.IMREAD_UNCHANGED)
        want = cv2.cvtColor(encode_image(img, settings.bit_depth, settings.encoding), cv2.COLOR_RGB2BGR)
        np.testing.assert_array_equal(got, want, err_msg=kind)


def test_a_frame_without_its_levels_takes_the_builtin_calibrations_picked_by_its_size(tmp_path):
    # No calibration in the settings: the built-in one for the frame's size gives the pattern
    # and levels the frame's file lacks (it was picked only after the frame was read, with the
    # levels 0 and 65535).
    import shutil
    from pathlib import Path

    scene = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    bare = tmp_path / "bare.png"
    shutil.copyfile(scene, bare)
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add")
    res, ref = process_frame(str(bare), settings), process_frame(str(scene), settings)
    assert res.ok and ref.ok, (res.error, ref.error)
    assert res.info["calibration"] == "twin_binned2"
    assert not any("levels assumed" in w for w in res.info.get("warnings", []))
    key = next(iter(ref.files))
    assert res.files[key] == ref.files[key]
