"""lfring.batch.settings: what BatchSettings refuses, and the keys of earlier versions' records,
what a refusal says differs from the run that made an output, and how lfring batch --refocus is
refused."""

from pathlib import Path

import pytest

from lfring.batch import BatchSettings
from lfring.errors import InvalidInputError


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({}, "nothing to do"),
        ({"refocus_m": (0.0,)}, "positive"),
        ({"refocus_m": (0.5, 0.5)}, "refocus_m: 0.5 m would be made more than once"),
        ({"refocus_m": (float("inf"),)}, "cannot refocus at infinity"),
        ({"depth": True, "zmin_m": -0.3}, "zmin_m must be a positive number of metres"),
        ({"depth": True, "zmin_m": 0.8, "zmax_m": 0.4}, "smaller"),
        ({"refocus_m": (0.5,), "bit_depth": 12}, "bit_depth"),
        ({"refocus_m": (0.5,), "planes": 1}, "planes"),
        # Two planes leave the semi-global depth nothing to judge its answers against: the
        # batch's own depth map, the viewer's, or the one depth-aware refocusing renders from.
        ({"depth": True, "zmin_m": 0.3, "zmax_m": 1.0, "planes": 2}, "planes must be an integer >= 3"),
        ({"viewer": True, "planes": 2}, "planes must be an integer >= 3"),
        ({"refocus_m": (0.5,), "planes": 2}, "planes must be an integer >= 3"),
    ],
)
def test_settings_errors(kwargs, text):
    with pytest.raises(InvalidInputError, match=text):
        BatchSettings(**kwargs)


def test_two_planes_serve_no_depth_method():
    # Every method judges a depth against the hypotheses more than a pixel of motion away: with
    # two there are none, and the local method's map came out with no confidence anywhere.
    for kwargs in (dict(refocus_m=(0.5,), refocus_method="shift-and-add"), dict(refocus_m=(0.5,), depth_method="local"),
                   dict(depth=True, depth_method="local")):
        with pytest.raises(InvalidInputError, match="planes must be an integer >= 3"):
            BatchSettings(planes=2, **kwargs)
    BatchSettings(depth=True, planes=3, depth_method="local")


def test_legacy_key_is_the_key_of_records_before_output_keys():
    # 6e76e9ced5695793 is what BatchSettings(refocus_m=(0.5,)).key() returned before per-output
    # keys (commit 188722c): folders made then resume instead of being refused.
    # (its default interpolation was cubic then).
    assert BatchSettings(refocus_m=(0.5,), interpolation="cubic").legacy_key() == "6e76e9ced5695793"
    assert BatchSettings(refocus_m=(0.5,), pattern="RGGB").legacy_key() is None


def test_refocusing_method_options():
    with pytest.raises(InvalidInputError, match="refocus_method must be one of"):
        BatchSettings(refocus_m=(0.5,), refocus_method="bokeh")
    with pytest.raises(InvalidInputError, match="for refocus_method='depth-aware'"):
        BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", aperture=0.5)
    with pytest.raises(InvalidInputError, match="not both"):
        BatchSettings(refocus_m=(0.5,), aperture=0.5, f_number=2.8)
    with pytest.raises(InvalidInputError, match="aperture must be"):
        BatchSettings(refocus_m=(0.5,), aperture=-1.0)
    assert BatchSettings(refocus_m=(0.5,)).refocus_method == "depth-aware"  # as lfring refocus


def test_refocus_keys_hold_the_method_and_its_aperture():
    """A folder refocused by one method is not done for another, nor for another aperture or
    depth range; shift-and-add's keys are the ones of the folders made before refocusing had a
    method (all of them shift-and-add), so those stay done for it."""
    sa = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add").output_keys()["refocus_0.5m"]
    assert sa == "17bef21df6197085"  # what lfring computed before methods were a setting
    keys = {BatchSettings(refocus_m=(0.5,), **kw).output_keys()["refocus_0.5m"]
            for kw in ({}, {"aperture": 0.5}, {"f_number": 2.8}, {"viewer": True, "zmin_m": 0.3, "zmax_m": 0.8})}
    assert len(keys) == 4 and sa not in keys
    viewers = {BatchSettings(viewer=True, refocus_method=m).output_keys()["viewer"] for m in ("depth-aware", "shift-and-add")}
    assert len(viewers) == 2
    d = BatchSettings(refocus_m=(0.5,), f_number=2.8).describe()
    assert d["refocus_method"] == "depth-aware" and d["f_number"] == 2.8


def test_an_all_in_focus_image_from_the_refocusing_depth_map_is_keyed_by_that_map():
    """With depth-aware refocusing the all-in-focus image comes from the depth map the images
    render from: the settings of that map make it (another depth range, another image); by
    photo-consistency (shift-and-add, or no refocusing) they do not."""
    def key(**kw):
        return BatchSettings(all_in_focus=True, **kw).output_keys()["all_in_focus"]

    assert key(refocus_m=(0.5,)) != key(refocus_m=(0.5,), zmin_m=0.3, zmax_m=0.8)
    assert key(refocus_m=(0.5,)) != key(refocus_m=(0.5,), refocus_method="shift-and-add")
    # The refocusing's aperture and depths make the refocused images, not this one.
    assert key(refocus_m=(0.5,)) == key(refocus_m=(0.5,), aperture=0.5) == key(refocus_m=(0.7,))
    sa = {"refocus_m": (0.5,), "refocus_method": "shift-and-add"}
    assert key(**sa) == key(**sa, zmin_m=0.3, zmax_m=0.8) == key()
    # The batch's own map (--depth) is the one the images render from: the same image, one key.
    assert key(refocus_m=(0.5,), depth=True) == key(refocus_m=(0.5,))
    # A rerun that adds depth-aware refocusing changes the image's source, and says so.
    then, now = BatchSettings(all_in_focus=True), BatchSettings(all_in_focus=True, refocus_m=(0.5,))
    assert now.differences("all_in_focus", _record(then)) == ["the all-in-focus image from a depth map (no then, yes now)"]


def test_a_calibration_without_a_depth_range_is_refused_when_a_depth_map_must_be_estimated():
    """The frames' depth maps for depth-aware refocusing and the viewer are estimated over
    lfring.focus.depth_aware.estimation_range: a grid pair's open range is refused at once,
    unless the batch is given the range or needs no depth map."""
    from lfring.calibration import RingCalibration
    from lfring.optics import load_device

    pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    for kw in ({"refocus_m": (12.0,)}, {"viewer": True}, {"refocus_m": (12.0,), "aperture": 0.5}):
        with pytest.raises(InvalidInputError, match="no upper depth bound, and none follows from it"):
            BatchSettings(calibration=pair, **kw)
    for kw in ({"refocus_m": (12.0,), "refocus_method": "shift-and-add"}, {"all_in_focus": True},
               {"refocus_m": (12.0,), "zmax_m": 30.0}, {"refocus_m": (12.0,), "zmin_m": 6.0},
               {"refocus_m": (12.0,), "viewer": True, "depth": True, "zmin_m": 6.0, "zmax_m": 30.0}):
        BatchSettings(calibration=pair, **kw)
    # A calibration from the optics gets its far end, as everywhere; a bounded one its range.
    BatchSettings(refocus_m=(0.5,), viewer=True, calibration=RingCalibration.from_optics(load_device("prototype").binned(4)))
    BatchSettings(refocus_m=(0.5,), viewer=True, calibration=RingCalibration.load("twin_binned2"))


def _record(settings):
    """A done frame's record as the batch writes it: the settings and the keys of their outputs."""
    return {"settings": settings.describe(), "output_keys": settings.output_keys(), "status": "done"}


def test_differences_name_only_the_settings_that_made_the_output():
    """The audit's rerun: images made by shift-and-add, asked for now by depth-aware refocusing
    with a depth method and range, which played no part in them. The refusal names the method,
    as the earlier run gave it, and nothing that made only one side's image."""
    then = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add")
    now = BatchSettings(refocus_m=(0.5, 0.7), depth_method="local", zmin_m=0.3, zmax_m=1.0)
    said = ["the refocusing method (shift-and-add then, depth-aware now)"]
    assert now.differences("refocus_0.5m", _record(then)) == said
    # Records of earlier versions left shift-and-add's method out of their settings.
    old = _record(then)
    old["settings"] = {k: v for k, v in old["settings"].items() if k not in ("refocus_method", "aperture", "f_number")}
    assert now.differences("refocus_0.5m", old) == said
    # The other way round: the depth-aware image's range is no difference of its own.
    assert then.differences("refocus_0.5m", _record(now)) == ["the refocusing method (depth-aware then, shift-and-add now)"]
    # Both depth-aware: the depth map's settings made both images, and are named.
    other = BatchSettings(refocus_m=(0.5,), depth_method="sgm", zmin_m=0.25, zmax_m=1.0)
    assert other.differences("refocus_0.5m", _record(now)) == ["the depth method (local then, sgm now)",
                                                                "zmin_m (0.3 then, 0.25 now)"]


def test_differences_leave_out_what_no_option_sets():
    """The semi-global depth's default cost is part of its maps' keys, but no option gives it:
    a rerun that turns the local sweep's maps into semi-global ones names the depth method only."""
    then = BatchSettings(depth=True, depth_method="local", zmin_m=0.3, zmax_m=1.0)
    now = BatchSettings(depth=True, zmin_m=0.3, zmax_m=1.0)
    for kind in ("depth", "confidence", "depth_preview"):
        assert now.differences(kind, _record(then)) == ["the depth method (local then, sgm now)"]
    assert then.differences("depth", _record(now)) == ["the depth method (sgm then, local now)"]


def test_differences_of_the_all_in_focus_image_name_its_source():
    then = BatchSettings(refocus_m=(0.5, 0.7), refocus_method="shift-and-add", all_in_focus=True)
    with_depth = BatchSettings(refocus_m=(0.5, 0.7), refocus_method="shift-and-add", all_in_focus=True, depth=True,
                               depth_method="local", zmin_m=0.3, zmax_m=1.0)
    assert with_depth.differences("all_in_focus", _record(then)) == ["the all-in-focus image from a depth map (no then, yes now)"]
    more = BatchSettings(refocus_m=(0.5, 0.7, 0.9), refocus_method="shift-and-add", all_in_focus=True)
    said = more.differences("all_in_focus", _record(then))
    assert said == ["the depths it chose from (0.5, 0.7 m then, 0.5, 0.7, 0.9 m now)"]
    assert not any(c in text for text in said for c in "[]'")  # no Python lists or strings


CLI_FRAME = str(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png")


@pytest.mark.parametrize(
    "refocus, text",
    [
        ("0.5,,0.7", ("Invalid value for --refocus: 0.5,,0.7 has an empty entry: give a depth in metres between every "
                      "two commas")),
        ("0.5,", "Invalid value for --refocus: 0.5, has an empty entry"),
        ("0.5,0.50", "Invalid value for --refocus: 0.5 m would be made more than once: give each depth once"),
        ("0.5,0.5000001", ("0.5 m would be made more than once: give each depth once (images are told apart by the "
                           "depth to 6 significant digits)")),
        ("inf", "Invalid value for --refocus: the batch cannot refocus at infinity (inf); give a finite depth in metres"),
        ("0,0.5", "Invalid value for --refocus: depths must be positive distances in metres, got 0"),
        ("nan", "Invalid value for --refocus: depths must be positive distances in metres, got nan"),
    ],
)
def test_cli_refocus_depths_are_refused_naming_the_option(refocus, text, tmp_path, capsys):
    from lfring.cli.main import main

    out = tmp_path / "out"
    assert main(["batch", CLI_FRAME, "-o", str(out), "--refocus", refocus, "--method", "shift-and-add"]) == 2
    (line,) = [t for t in capsys.readouterr().err.splitlines() if t.startswith("Error: ")]
    assert text in line and "refocus_m" not in line and "[" not in line
    assert not out.exists()  # refused before any work


def test_aperture_without_refocused_images_or_a_viewer_is_refused():
    """The aperture sets the depth of field of refocused images and of the viewer's stack: given
    for a batch that only makes depth maps or all-in-focus images it would change nothing, and
    its record would name an f-number no output was made with."""
    for kw in (dict(depth=True, aperture=2.0), dict(depth=True, f_number=4.0), dict(all_in_focus=True, aperture=2.0)):
        with pytest.raises(InvalidInputError, match="aperture and f_number set the depth of field"):
            BatchSettings(**kw)
    BatchSettings(viewer=True, aperture=2.0)
    BatchSettings(refocus_m=(0.5,), depth=True, f_number=4.0)


@pytest.mark.parametrize("options, flags", [(["--depth", "--method", "shift-and-add"], "--method chooses"),
                                            (["--depth", "--aperture", "2"], "--aperture chooses"),
                                            (["--all-in-focus", "--method", "depth-aware", "--f-number", "4"],
                                             "--method, --f-number choose")])
def test_cli_method_and_aperture_without_refocused_images_or_a_viewer_are_refused(options, flags, tmp_path, capsys):
    from lfring.cli.main import main

    out = tmp_path / "out"
    assert main(["batch", CLI_FRAME, "-o", str(out), *options]) == 2
    (line,) = [t for t in capsys.readouterr().err.splitlines() if t.startswith("Error: ")]
    assert flags in line and "--depth and --all-in-focus have no method or depth of field" in line
    assert not out.exists()  # refused before any work
