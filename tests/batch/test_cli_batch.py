"""`lfring batch`: failures named once, exit codes, usage errors."""

import pytest
from batch_frames import CORRUPT, N_FRAMES, load_calibration, make_folder, render_frames

from lfring.cli.main import main


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


@pytest.fixture
def folder(frames, tmp_path):
    """50 frames in nested folders, 3 of them corrupt."""
    d, _ = frames
    return make_folder(d, tmp_path / "in")


def test_cli_batch_names_failures_and_exits_1(frames, folder, tmp_path, capsys):
    _, cal_path = frames
    root, _ = folder
    out = tmp_path / "out"
    # Shift-and-add: the subject is how failures are told, not the method (the default method's batch
    # is judged below).
    run = ["batch", str(root), "-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--calib", str(cal_path),
           "--workers", "1", "--interpolation", "linear", "--no-progress"]
    code = main(run)
    assert code == 1
    captured = capsys.readouterr()
    # Each failure is printed once, as it happens: "lfring: ERROR: PATH: why".
    failed = [line for line in captured.err.splitlines() if line.startswith("lfring: ERROR: ")]
    assert sorted(line.split(": ")[2] for line in failed) == sorted(str(root / c) for c in CORRUPT)
    for c in CORRUPT:
        assert captured.err.count(str(root / c)) == 1
    assert f"{N_FRAMES} frames: {N_FRAMES - 3} done, 0 skipped (already done), 3 failed" in captured.out
    # Rerun: all good frames skipped, exit 1 again for the corrupt ones.
    assert main(run) == 1
    assert f"0 done, {N_FRAMES - 3} skipped" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, text",
    [
        ([], "nothing to do"),
        (["--refocus", "0.5", "--method", "shift-and-add", "--zmin", "0.3"], "go with --depth"),
        (["--depth", "--zmin", "0.8", "--zmax", "0.4"], "--zmin (0.8) must be smaller than --zmax (0.4)"),
        (["--refocus", "0.5", "--workers", "0"], "workers"),
        (["--refocus", "abc"], "comma-separated"),
        (["--refocus", "0.5", "--reference", "7"], "reference"),
        (["--depth", "--planes", "2"], "--planes must be an integer >= 3"),
    ],
)
def test_cli_usage_errors_exit_2(frames, tmp_path, capsys, args, text):
    d, cal_path = frames
    assert main(["batch", str(d / "scene.png"), "-o", str(tmp_path / "o"), "--calib", str(cal_path), *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
    assert main(["batch", str(tmp_path / "nothing_here"), "-o", str(tmp_path / "o"), "--refocus", "0.5"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_cli_batch_refocuses_as_lfring_refocus_and_records_the_method(frames, tmp_path, capsys):
    """`lfring batch --refocus` uses lfring refocus's default method (depth-aware), each record
    says which method and aperture made the images, and a folder refocused by one method is not
    taken as done by the other."""
    import json

    import cv2
    import numpy as np
    from batch_frames import expected_refocus

    d, cal_path = frames
    out = tmp_path / "o"
    args = ["batch", str(d / "scene.png"), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers", "1",
            "--no-progress"]
    assert main(args) == 0
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert rec["settings"]["refocus_method"] == "depth-aware" and rec["info"]["refocus_method"] == "depth-aware"
    assert rec["info"]["aperture"] == 1.0
    img = cv2.cvtColor(cv2.imread(str(out / "scene_refocus_0.5m.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, expected_refocus(d / "scene.png", cal_path, 0.5))
    # The same folder with shift-and-add: not done, its images were made by another method.
    assert main([*args, "--method", "shift-and-add"]) == 1
    assert "other settings" in capsys.readouterr().err
    assert main([*args, "--method", "shift-and-add", "--overwrite"]) == 0
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert rec["info"]["refocus_method"] == "shift-and-add" and rec["info"]["aperture"] is None
    img = cv2.cvtColor(cv2.imread(str(out / "scene_refocus_0.5m.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, expected_refocus(d / "scene.png", cal_path, 0.5, method="shift-and-add"))
    # An f-number becomes the aperture of the calibration's device (the prototype's optics).
    assert main([*args, "--f-number", "4", "--overwrite"]) == 0
    from lfring.focus import resolve_aperture
    from lfring.optics import load_device

    rec = json.loads((out / "scene.lfring.json").read_text())
    assert rec["info"]["f_number"] == 4.0
    assert rec["info"]["aperture"] == pytest.approx(resolve_aperture(load_calibration(cal_path), f_number=4.0))
    assert rec["info"]["aperture"] == pytest.approx(resolve_aperture(load_calibration(cal_path), f_number=4.0,
                                                                     ring_device=load_device("prototype")))
    assert main([*args, "--method", "shift-and-add", "--aperture", "0.5"]) == 2
    assert "--method depth-aware" in capsys.readouterr().err


def test_an_optics_calibration_gets_one_depth_range_from_refocus_batch_and_the_api(frames, tmp_path):
    """A calibration from the optics has no upper depth bound and gets the far end of
    lfring.focus.depth_aware.estimation_range everywhere: lfring refocus takes it without
    --zmax (its sidecar records the range), and its image is lfring batch's and lfring.refocus's."""
    import json

    import cv2
    import numpy as np
    from batch_frames import expected_refocus

    from lfring.focus.depth_aware import estimation_range

    d, cal_path = frames
    cal = load_calibration(cal_path)
    assert cal.source == "optics" and cal.valid_depth_range_m[1] is None
    lo, hi = estimation_range(cal)
    single = tmp_path / "r.png"
    assert main(["refocus", str(d / "scene.png"), "--depth", "0.5", "--calib", str(cal_path), "-o", str(single)]) == 0
    side = json.loads((tmp_path / "r.png.json").read_text())
    assert (side["zmin_m"], side["zmax_m"]) == (lo, hi)
    out = tmp_path / "o"
    assert main(["batch", str(d / "scene.png"), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers",
                 "1", "--no-progress"]) == 0
    cli = cv2.imread(str(single))
    np.testing.assert_array_equal(cli, cv2.imread(str(out / "scene_refocus_0.5m.png")))
    np.testing.assert_array_equal(cv2.cvtColor(cli, cv2.COLOR_BGR2RGB), expected_refocus(d / "scene.png", cal_path, 0.5))
    # The all-in-focus image takes its depths from the same range.
    from lfring import demosaic, load_raw, split_views
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.focus import all_in_focus

    views = split_views(demosaic(load_raw(d / "scene.png")), cal.layout)
    _, chosen = all_in_focus(views, cal)
    hyps = depth_hypotheses(cal, lo, hi)
    picked = np.unique(chosen[np.isfinite(chosen)])
    assert picked.size > 1 and np.isin(picked, hyps.astype(np.float32)).all()
    assert main(["refocus", str(d / "scene.png"), "--depth", "0.5", "--all-in-focus", "--calib", str(cal_path),
                 "-o", str(tmp_path / "a.png")]) == 0
    # With depth-aware refocusing it is made from the depth map the images render from, by
    # lfring refocus and by lfring batch alike (with --depth, from the map it saves: the same).
    assert json.loads((tmp_path / "a_all_in_focus.png.json").read_text())["all_in_focus_depths_m"] == "depth map"
    cli_aif = cv2.imread(str(tmp_path / "a_all_in_focus.png"))
    for extra in ([], ["--depth"]):
        aif = tmp_path / f"aif{len(extra)}"
        assert main(["batch", str(d / "scene.png"), "-o", str(aif), "--refocus", "0.5", "--all-in-focus", *extra,
                     "--calib", str(cal_path), "--workers", "1", "--no-progress"]) == 0
        np.testing.assert_array_equal(cli_aif, cv2.imread(str(aif / "scene_all_in_focus.png")))
    # So does a rerun that adds it to the refocused image made above (that one is not made again).
    made = (out / "scene_refocus_0.5m.png").stat().st_mtime_ns
    assert main(["batch", str(d / "scene.png"), "-o", str(out), "--refocus", "0.5", "--all-in-focus", "--calib",
                 str(cal_path), "--workers", "1", "--no-progress"]) == 0
    assert (out / "scene_refocus_0.5m.png").stat().st_mtime_ns == made
    np.testing.assert_array_equal(cli_aif, cv2.imread(str(out / "scene_all_in_focus.png")))
    # So does lfring depth without --zmax.
    assert main(["depth", str(d / "scene.png"), "--calib", str(cal_path), "--method", "local", "-o", str(tmp_path / "dep")]) == 0
    rec = json.loads((tmp_path / "dep" / "scene_depth.json").read_text())
    assert (rec["zmin_m"], rec["zmax_m"]) == (lo, hi)
