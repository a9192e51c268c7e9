import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring.cli.main import main

SCENE = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"


def test_refocus_sample_with_default_calibration(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["refocus", str(SCENE), "--depth", "0.5"]) == 0
    assert "built-in calibration 'twin_binned2'" in capsys.readouterr().err
    out = tmp_path / "scene_refocus_0.5m.png"
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (705, 705, 3)
    side = json.loads((tmp_path / "scene_refocus_0.5m.png.json").read_text())
    assert side["calibration"] == "twin_binned2" and side["depth_m"] == 0.5 and side["encoding"] == "srgb"
    # The same command again replaces its own outputs; a file it did not make is not replaced
    # without --overwrite.
    assert main(["refocus", str(SCENE), "--depth", "0.5"]) == 0
    (tmp_path / "scene_refocus_0.5m.png.lfring.json").unlink()
    assert main(["refocus", str(SCENE), "--depth", "0.5"]) == 2


def test_refocus_stack_and_all_in_focus(tmp_path):
    out = tmp_path / "st" / "s.png"
    assert main(["refocus", str(SCENE), "--depths", "0.3,0.5,1.0", "--all-in-focus", "--bit-depth", "16",
                 "--encoding", "linear", "-o", str(out)]) == 0
    names = sorted(p.name for p in out.parent.iterdir())
    for expected in ("s_000_0.3m.png", "s_001_0.5m.png", "s_002_1m.png", "s_stack.tif", "s_stack.gif",
                     "s_all_in_focus.png", "s_all_in_focus.png.json"):
        assert expected in names
    import tifffile

    stack = tifffile.imread(out.parent / "s_stack.tif")
    assert stack.shape == (3, 705, 705, 3) and stack.dtype == np.uint16
    from gif_frames import read_gif

    assert read_gif(out.parent / "s_stack.gif").shape[0] == 3


@pytest.mark.parametrize("args", [["refocus", str(SCENE), "--depths", "0.3,0.5", "--all-in-focus", "-o", "s.png"],
                                  ["view", str(SCENE), "-o", "v.html"]], ids=["refocus", "view"])
def test_the_stack_and_the_all_in_focus_image_share_one_renderer(tmp_path, monkeypatch, renderers_made, args):
    """The depth-aware stack and the all-in-focus image render from one depth map: its renderer
    (the all-in-focus colour, the background) is prepared once for both."""
    monkeypatch.chdir(tmp_path)
    assert main(["-q", *args]) == 0
    assert len(renderers_made) == 1


@pytest.mark.parametrize(
    "args, text",
    [
        (["--depth", "0"], "Invalid value for --depth: depths must be positive"),
        (["--depth", "nan"], "positive"),
        (["--depths", ","], "Invalid value for --depths: expected comma-separated metres, got no number"),
        (["--depths", " "], "got no number"),
        (["--depths", "0.3,,0.5"], "Invalid value for --depths: 0.3,,0.5 has an empty entry"),
        (["--depths", "0.5,0.3,0.5"], "Invalid value for --depths: 0.5 m would be made more than once"),
        (["--sweep", "0.3:0.3:3"], "Invalid value for --sweep: 0.3 m would be made more than once"),
        (["--sweep", "-0.3:0.3:3"], "Invalid value for --sweep: depths must be positive"),
        (["--sweep", "0.3:1"], "Invalid value for --sweep: expected START:STOP:N, got '0.3:1'"),
        (["--depth", "0.5", "--f-number", "0.1"], "--f-number must be an f-number >= 0.5 (finite): no lens in air"),
        (["--sweep", "0.3:1:1"], "Invalid value for --sweep: N must be >= 2, got 1"),
        (["--sweep", "a:1:3"], "Invalid value for --sweep: START and STOP must be numbers in metres"),
        (["--depth", "0.5", "--depths", "0.3,0.6"], "exactly one of"),
        (["--depth", "0.5", "--reference", "north"], "reference"),
        (["--depth", "0.5", "-o", "x.jpg"], ".png, .tif"),
        (["--depth", "0.5", "--aperture", "1", "--f-number", "2"], "as --aperture or as --f-number, not both"),
    ],
)
def test_refocus_errors(tmp_path, capsys, args, text):
    assert main(["refocus", str(SCENE), *args, "-o" if "-o" not in args else "--overwrite",
                 *([str(tmp_path / "o.png")] if "-o" not in args else [])]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


def test_refocus_frame_without_calibration(tmp_path, capsys, prototype):
    from lfring.cli.synth import write_render
    from lfring.synth import render
    from lfring.synth.presets import target_scene

    write_render(render(prototype, target_scene(prototype, 0.5), binning=8), tmp_path / "small.png")
    assert main(["refocus", str(tmp_path / "small.png"), "--depth", "0.5", "-o", str(tmp_path / "o.png")]) == 2
    assert "no built-in calibration for 614 x 460 px" in capsys.readouterr().err
    cal = Path(__file__).resolve().parents[2] / "calib" / "twin_binned2.json"
    assert main(["refocus", str(tmp_path / "small.png"), "--depth", "0.5", "--calib", str(cal), "-o", str(tmp_path / "o.png")]) == 2
    assert "614 x 460 px but the calibration is for 2456 x 1842" in capsys.readouterr().err


def test_refocus_sidecar_says_which_method_and_aperture(tmp_path):
    """Every sidecar names the method and the aperture that made its image: depth-aware's,
    resolved from --f-number through the calibration's device; shift-and-add has none."""
    cal = Path(__file__).resolve().parents[2] / "calib" / "twin_binned2.json"
    out = tmp_path / "f.png"
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--calib", str(cal), "--f-number", "2.8", "--zmin", "0.3",
                 "--zmax", "0.9", "-o", str(out)]) == 0
    from lfring.focus.depth_aware import aperture_from_f_number
    from lfring.optics import load_device

    side = json.loads(Path(str(out) + ".json").read_text())
    assert side["method"] == "depth-aware" and side["f_number"] == 2.8 and side["f_number_device"] == "prototype"
    assert side["aperture"] == pytest.approx(aperture_from_f_number(2.8, load_device("prototype")))
    # The set's record too: its settings as typed (no aperture), and what they made.
    record = json.loads((tmp_path / "f.png.lfring.json").read_text())
    assert record["settings"]["aperture"] is None and record["settings"]["f_number"] == 2.8
    assert record["made_with"] == {"method": "depth-aware", "aperture": side["aperture"]}
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", str(tmp_path / "s.png")]) == 0
    side = json.loads((tmp_path / "s.png.json").read_text())
    assert side["method"] == "shift-and-add" and side["aperture"] is None
    assert json.loads((tmp_path / "s.png.lfring.json").read_text())["made_with"] == {"method": "shift-and-add",
                                                                                      "aperture": None}


def test_sweep_metadata_holds_the_depths_as_written(tmp_path):
    """A sweep's depths were written as 0.44999999999999996; infinity is the documented "inf"."""
    out = tmp_path / "st" / "s.png"
    assert main(["refocus", str(SCENE), "--sweep", "0.3:1.0:15", "--method", "shift-and-add", "-o", str(out)]) == 0
    side = (out.parent / "s_003_0.45m.png.json").read_text()
    assert '"depth_m": 0.45' in side and "0.4499999" not in side
    import tifffile

    with tifffile.TiffFile(out.parent / "s_stack.tif") as tif:
        assert "0.4499999" not in tif.pages[0].description and "0.45" in tif.pages[0].description
        meta = json.loads(tif.pages[0].description)
        # How the pages are encoded (a linear stack reads otherwise than an sRGB one) and made.
        assert (meta["encoding"], meta["bit_depth"], meta["method"]) == ("srgb", 8, "shift-and-add")
    assert "0.4499999" not in "".join(p.name for p in out.parent.iterdir())


def test_a_flat_that_is_not_a_flat_frame_is_refused(tmp_path, capsys):
    """--flat divides every view by the given frame: a scene or a target there would print its
    texture into the views, so only a flat (white) frame of the camera is taken."""
    data = SCENE.parent
    for frame in ("target_1m.png", "scene.png"):
        assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "--flat", str(data / frame),
                     "-o", str(tmp_path / "o.png")]) == 2
        err = capsys.readouterr().err
        assert f"--flat {data / frame} is not a flat (white) frame of this camera" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "--flat", str(data / "flat.png"),
                 "-o", str(tmp_path / "o.png")]) == 0
    # --no-check, which a refusal of an over-exposed flat offers, takes the frame as the flat (it
    # was refused all the same).
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "--flat", str(data / "scene.png"),
                 "--no-check", "-o", str(tmp_path / "n.png")]) == 0


def test_view_images_out_of_order_or_from_two_frames_are_refused(tmp_path, capsys):
    """Separate view images of a ring calibration must agree as one frame's views do: in
    another order (or mixed from two frames) they are refused, unless --no-check."""
    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    calib = str(Path(__file__).resolve().parents[2] / "calib" / "twin_binned2.json")
    assert main(["-q", "split", str(data / "scene.png"), "--flat", str(data / "flat.png"), "-o", str(tmp_path / "v")]) == 0
    views = [str(tmp_path / "v" / f"scene_view{k}.png") for k in range(4)]
    run = ["refocus", "--calib", calib, "--depth", "0.5", "--method", "shift-and-add"]
    assert main([*run[:1], *views, *run[1:], "-o", str(tmp_path / "ok.png")]) == 0
    capsys.readouterr()
    swapped = [views[1], views[0], views[3], views[2]]
    assert main([*run[:1], *swapped, *run[1:], "-o", str(tmp_path / "no.png")]) == 2
    err = capsys.readouterr().err
    assert "do not agree as the views of one frame in this order (ZNCC 0.0" in err and "--no-check" in err
    assert not (tmp_path / "no.png").exists()
    assert main([*run[:1], *swapped, *run[1:], "-o", str(tmp_path / "no.png"), "--no-check"]) == 0


def test_view_images_are_corrected_as_a_frame_s_split_views(tmp_path, capsys):
    """Views written by lfring split are as cut from the frame; a calibration that carries a
    flat field (the built-in twin_binned2) or lens distortion corrects a frame's views when it
    splits them, but view images were used as they were: their refocused image differed from
    the frame's by 3.5/255 on average (and with a distortion, depth by centimetres). Options
    that only a raw frame can use are refused for view images, where they were ignored."""
    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    calib = str(Path(__file__).resolve().parents[2] / "calib" / "twin_binned2.json")
    assert main(["-q", "split", str(data / "scene.png"), "--flat", str(data / "flat.png"), "-o", str(tmp_path / "v")]) == 0
    views = [str(tmp_path / "v" / f"scene_view{k}.png") for k in range(4)]
    run = ["--calib", calib, "--depth", "0.5", "--method", "shift-and-add", "--bit-depth", "16", "--encoding", "linear"]
    assert main(["refocus", str(data / "scene.png"), *run, "-o", str(tmp_path / "frame.png")]) == 0
    assert main(["refocus", *views, *run, "-o", str(tmp_path / "views.png")]) == 0
    a, b = (cv2.imread(str(tmp_path / n), cv2.IMREAD_UNCHANGED) / 65535.0 for n in ("frame.png", "views.png"))
    assert np.abs(a - b).mean() < 2e-4 and np.abs(a - b).max() < 0.01
    capsys.readouterr()
    for extra in (["--flat", str(data / "flat.png")], ["--black-level", "0"], ["--pattern", "rggb"]):
        assert main(["refocus", *views, *run, *extra, "-o", str(tmp_path / "x.png")]) == 2
        err = capsys.readouterr().err
        assert f"{extra[0]} apply to one raw frame: separate view images are read as RGB images" in err


def test_a_stack_s_default_names_say_stack_once(tmp_path, capsys, monkeypatch):
    """Without -o a stack's files were named scene_stack_stack.tif (and .gif, and its record):
    the default name carries _stack, and the stack's files added it again."""
    monkeypatch.chdir(tmp_path)
    assert main(["refocus", str(SCENE), "--depths", "0.3,0.5", "--method", "shift-and-add"]) == 0, capsys.readouterr().err
    stem = "scene_stack_shift-and-add"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([
        f"{stem}_000_0.3m.png", f"{stem}_000_0.3m.png.json", f"{stem}_001_0.5m.png", f"{stem}_001_0.5m.png.json",
        f"{stem}.tif", f"{stem}.gif", f"{stem}.png.lfring.json"])


def test_stack_names_keep_the_depths_apart_and_a_folder_for_o_is_named(tmp_path, capsys, monkeypatch):
    """Two depths that round alike to four digits were both named 0.5m; -o given as a folder
    was reported as the name 'rdir' without its slash."""
    monkeypatch.chdir(tmp_path)
    assert main(["refocus", str(SCENE), "--depths", "0.5,0.50001", "--method", "shift-and-add", "-o", "s.png"]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"s_000_0.5m.png", "s_001_0.50001m.png"} <= names, names
    capsys.readouterr()
    assert main(["refocus", str(SCENE), "--depth", "0.5", "-o", "rdir/"]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "-o names the image file to write (.png, .tif or .tiff), got the folder 'rdir/'; e.g. -o rdir/scene_refocus.png" in err
    assert not (tmp_path / "rdir").exists()


def test_whole_frames_given_as_many_images_are_pointed_to_batch(tmp_path, capsys, monkeypatch):
    """An unquoted pattern hands refocus every frame it matches: they are frames, not a view
    set that lacks --calib."""
    monkeypatch.chdir(tmp_path)  # the default output name lands in the working folder
    assert main(["refocus", str(SCENE), str(SCENE.parent / "hard.png"), "--depth", "0.5"]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "2 ring frames given (whole frames of a built-in calibration's size): lfring refocus takes one frame; for " \
           "many, lfring batch FILES... --refocus Z" in err


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_a_stack_reaching_infinity_makes_its_all_in_focus_image(tmp_path, capsys):
    """--depths Z,inf with --all-in-focus failed after the stack was made: the all-in-focus
    image's depths reached the model's limit as an inverse depth of 0."""
    out = tmp_path / "s.png"
    assert main(["refocus", str(SCENE), "--depths", "0.5,inf", "--method", "shift-and-add", "--all-in-focus",
                 "-o", str(out)]) == 0, capsys.readouterr().err
    meta = json.loads((tmp_path / "s_all_in_focus.png.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert meta["all_in_focus_depths_m"] == [0.5, "inf"] and meta["chosen_depth_range_m"][1] == "inf"
    assert cv2.imread(str(tmp_path / "s_all_in_focus.png")).mean() > 20


@pytest.mark.parametrize("args, text", [(["--aperture", "-1"], "--aperture must be a number >= 0"),
                                        (["--f-number", "0.1"], "--f-number must be an f-number >= 0.5"),
                                        (["--aperture", "1", "--f-number", "2"], "not both")])
def test_a_bad_aperture_is_said_before_an_existing_output(tmp_path, capsys, args, text):
    """Where the output exists, a bad aperture option was refused only after --overwrite was
    passed (the refusal for the existing file came first): the option's own error comes first,
    and the file stays."""
    out = tmp_path / "o.png"
    out.write_bytes(b"someone's file")
    assert main(["refocus", str(SCENE), "--depth", "0.3", *args, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert text in err and "exists" not in err and "Traceback" not in err
    assert out.read_bytes() == b"someone's file"
