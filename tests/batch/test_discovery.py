"""lfring.batch.discovery: files, folders and globs into jobs, what is not a frame, and output
names that collide."""

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from batch_frames import copy_frame, load_calibration, render_frames

from lfring.batch import BatchSettings, find_inputs, plan_jobs, run_batch
from lfring.errors import InvalidInputError


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


def test_inputs_outputs_and_names(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    copy_frame(d / "scene.png", root / "a.png")
    shutil.copyfile(d / "scene.png", root / "a.tif")
    (root / ".hidden.png").write_bytes(b"x")
    (root / "notes.txt").write_text("not a frame")
    settings = BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path))
    jobs = find_inputs([str(root)])
    assert sorted(Path(j.input).name for j in jobs) == ["a.png", "a.tif"]
    with pytest.raises(InvalidInputError, match="would both write"):
        plan_jobs(jobs, settings, tmp_path / "out")
    assert [Path(j.input).name for j in find_inputs([str(root)], exclude=["*.tif"])] == ["a.png"]
    assert [Path(j.input).name for j in find_inputs([str(root / "*.png")])] == ["a.png"]
    with pytest.raises(InvalidInputError, match="matches no files"):
        find_inputs([str(root / "*.dng")])
    with pytest.raises(InvalidInputError, match="no such file"):
        find_inputs([str(root / "missing.png")])
    # An output folder inside the input folder: its files are never inputs, even on a rerun.
    (root / "a.tif").unlink()
    out = root / "results"
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.done == [str(root / "a.png")]
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.skipped == [str(root / "a.png")] and rep.done == []


def test_scan_inputs_leaves_out_what_is_not_a_frame(tmp_path):
    import tifffile

    from lfring.batch import scan_inputs

    root = tmp_path / "in"
    (root / "x_truth").mkdir(parents=True)
    cv2.imwrite(str(root / "a.png"), np.zeros((8, 10), np.uint16))
    (root / "a.png.json").write_text("{}")
    cv2.imwrite(str(root / "small.png"), np.zeros((4, 6), np.uint16))
    tifffile.imwrite(root / "map.tiff", np.zeros((8, 10), np.float32))
    (root / "x_truth" / "depth.tiff").write_bytes(b"")
    (root / "broken.png").write_bytes(b"")  # unreadable: kept, its own error says why
    jobs, skipped = scan_inputs([str(root)], frame_sizes={(10, 8)})
    assert sorted(Path(j.input).name for j in jobs) == ["a.png", "broken.png"]
    reasons = {Path(p).name: why for p, why in skipped}
    assert reasons == {"x_truth": "a ground-truth folder", "a.png.json": "a sidecar or record (JSON)",
                       "small.png": "6 x 4 px, a size no calibration fits", "map.tiff": "float samples (a map, not raw counts)"}
    # A file named explicitly is always taken.
    assert [Path(j.input).name for j in scan_inputs([str(root / "small.png")], frame_sizes={(10, 8)})[0]] == ["small.png"]


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="needs named pipes")
def test_a_named_pipe_is_not_opened(tmp_path):
    """A named pipe (or a device) under a frame's name would block the first read until a writer
    came: in a folder it is left out, named on its own it is refused, and load_raw refuses it."""
    import os

    import lfring
    from lfring.batch import scan_inputs
    from lfring.errors import FileFormatError

    root = tmp_path / "in"
    root.mkdir()
    cv2.imwrite(str(root / "a.png"), np.zeros((8, 10), np.uint16))
    os.mkfifo(root / "pipe.png")
    jobs, skipped = scan_inputs([str(root)], frame_sizes={(10, 8)})
    assert [Path(j.input).name for j in jobs] == ["a.png"]
    assert (str(root / "pipe.png"), "not a regular file") in skipped
    with pytest.raises(InvalidInputError, match="pipe.png: not a regular file"):
        scan_inputs([str(root / "pipe.png")], frame_sizes={(10, 8)})
    with pytest.raises(FileFormatError, match="not a regular file"):
        lfring.load_raw(root / "pipe.png")


def test_a_folder_of_frames_of_another_size_says_so(tmp_path, caplog):
    """A folder whose frames are all of a size the run's calibration does not read: the run
    said 'no frames found (suffixes ...)', as if the files were not images, and -v listed
    nothing. The error names the size, a frame and the sizes the run reads; the summary counts
    such frames apart from files that are not frames."""
    from lfring.batch import BatchReport, scan_inputs
    from lfring.errors import InvalidInputError

    root = tmp_path / "in"
    root.mkdir()
    cv2.imwrite(str(root / "scene.png"), np.zeros((4, 6), np.uint16))
    (root / "scene.png.json").write_text("{}")
    with pytest.raises(InvalidInputError) as info:
        scan_inputs([str(root)], frame_sizes={(10, 8)})
    assert str(info.value) == (f"no frames found in {root}: 1 file left out for a size no calibration fits, as "
                               f"{root / 'scene.png'} (6 x 4 px); the calibration of this run reads frames of 10 x 8 px")
    assert "no frames of a size a calibration fits (10 x 8 px); 1 left out for their size" in caplog.text
    with pytest.raises(InvalidInputError, match="calibrations of this run read frames of 10 x 8 px or 12 x 9 px"):
        scan_inputs([str(root)], frame_sizes={(12, 9), (10, 8)})
    cv2.imwrite(str(root / "good.png"), np.zeros((8, 10), np.uint16))
    jobs, skipped = scan_inputs([str(root)], frame_sizes={(10, 8)})
    report = BatchReport(str(tmp_path / "out"), not_frames=skipped)
    assert report.summary().endswith("; 1 frame of a size no calibration fits and 1 file that is not a frame left out")


def test_inputs_in_the_output_folder_links_and_exclude_paths(tmp_path, caplog, monkeypatch):
    """An input inside the output folder is refused as such (not 'no frames found'); a link
    beside its target is one job, the target's; --exclude takes a path as given, and a pattern
    that matches nothing is warned about."""
    monkeypatch.chdir(tmp_path)
    root = Path("in")
    root.mkdir()
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(root / name), np.zeros((8, 10), np.uint16))
    for inp, out in ((root, root), (root / "a.png", root), (root, tmp_path)):
        with pytest.raises(InvalidInputError, match="lies in the output folder .*give another output folder"):
            find_inputs([str(inp)], outdir=out)
    (root / "0link.png").symlink_to("b.png")  # sorted first
    assert sorted(Path(j.input).name for j in find_inputs([str(root)])) == ["a.png", "b.png"]
    (root / "0link.png").unlink()
    with caplog.at_level("WARNING", logger="lfring.batch"):
        for pattern in ("in/b.png", "./in/b.png", "*/b.png", str(tmp_path / "in" / "b.png")):
            caplog.clear()
            arg = str(tmp_path / "in") if pattern.startswith("/") else "in"
            kept = find_inputs([arg], exclude=[pattern, "nothing*.png"])
            assert [Path(j.input).name for j in kept] == ["a.png"], pattern
            assert "'nothing*.png' matched no input file" in caplog.text and repr(pattern) not in caplog.text


def test_an_output_folder_under_a_file_is_refused_in_words(tmp_path):
    from lfring.batch import BatchSettings, run_batch

    (tmp_path / "a.json").write_text("{}")
    frame = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    with pytest.raises(InvalidInputError, match=r"cannot make the folder .*a\.json/x: .*a\.json is a file, not a folder"):
        run_batch([str(frame)], tmp_path / "a.json" / "x", BatchSettings(refocus_m=(0.5,)))
    with pytest.raises(InvalidInputError, match=r"cannot write into .*a\.json: it is a file, not a folder"):
        run_batch([str(frame)], tmp_path / "a.json", BatchSettings(refocus_m=(0.5,)))
