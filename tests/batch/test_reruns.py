"""lfring batch reruns and what its records claim: a record and a manifest line list only files
that exist and that run wrote, a manifest.jsonl the batch did not write is left alone, a rerun
that adds --depth keeps the refocused images it would make again, and --zmin/--zmax/--depth
follow lfring refocus and lfring depth."""

import json
import shutil

import cv2
import numpy as np
import pytest
from batch_frames import copy_frame, load_calibration, render_frames

from lfring.batch import BatchSettings, read_manifest, run_batch
from lfring.cli.main import main
from lfring.errors import InvalidInputError


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin, an optics calibration (open to infinity)
    and the same calibration with the valid range 0.3..1.0 m (as the built-in ones have)."""
    d, cal_path = render_frames(tmp_path_factory.mktemp("render"))
    data = json.loads(cal_path.read_text())
    data["valid_depth_range_m"] = [0.3, 1.0]
    bounded = d / "cal_bounded.json"
    bounded.write_text(json.dumps(data))
    return d, cal_path, bounded


def _listed_outputs(out):
    """Every file that a record or a manifest line of ``out`` lists as an output."""
    listed = set()
    for rec in out.rglob("*.lfring.json"):
        listed |= set(json.loads(rec.read_text())["outputs"].values())
    for e in read_manifest(out / "manifest.jsonl"):
        listed |= set(e["outputs"])
    return listed


# -- 1. records list only files that exist and that run wrote ------------------------------------
def test_failed_frames_list_no_outputs_and_resume(frames, tmp_path):
    d, _, bounded = frames
    root = tmp_path / "in"
    copy_frame(d / "scene.png", root / "a.png")
    (root / "bad.png").write_bytes((d / "scene.png").read_bytes()[:1000])
    out = tmp_path / "out"
    cal = load_calibration(bounded)
    first = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=cal)
    rep = run_batch([str(root)], out, first, workers=1)
    assert rep.failed == [str(root / "bad.png")] and rep.done == [str(root / "a.png")]
    bad = json.loads((out / "bad.lfring.json").read_text())
    assert bad["status"] == "failed" and bad["outputs"] == {}
    assert bad["planned_outputs"] == {"refocus_0.5m": "bad_refocus_0.5m.png"}
    entries = {e["input"]: e for e in read_manifest(out / "manifest.jsonl")}
    assert entries[str(root / "bad.png")]["outputs"] == []
    assert entries[str(root / "bad.png")]["planned_outputs"] == ["bad_refocus_0.5m.png"]
    assert entries[str(root / "a.png")]["outputs"] == ["a_refocus_0.5m.png"]

    # A rerun adds a depth map over a range too narrow for it: the frame fails; its record keeps
    # the earlier image (it exists), lists the depth files only as planned, and its manifest
    # line lists nothing; a skipped frame's line lists nothing either (that run wrote nothing).
    narrow = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", depth=True, zmin_m=0.3, zmax_m=0.31,
                           calibration=cal)
    rep = run_batch([str(root / "a.png")], out, narrow, workers=1)
    assert rep.failed == [str(root / "a.png")]
    assert "is too narrow to estimate depth over" in rep.errors[str(root / "a.png")]
    assert "method=" not in rep.errors[str(root / "a.png")]
    rec = json.loads((out / "a.lfring.json").read_text())
    assert rec["status"] == "failed" and rec["outputs"] == {"refocus_0.5m": "a_refocus_0.5m.png"}
    assert set(rec["planned_outputs"]) == {"depth", "confidence", "depth_preview"}
    assert read_manifest(out / "manifest.jsonl")[-1]["outputs"] == []
    assert all((out / rel).is_file() for rel in _listed_outputs(out))
    rep = run_batch([str(root / "a.png")], out, first, workers=1)
    assert rep.skipped == [str(root / "a.png")] and read_manifest(out / "manifest.jsonl")[-1]["outputs"] == []

    # The same rerun over a workable range resumes: only the depth files are computed.
    stamp = (out / "a_refocus_0.5m.png").stat().st_mtime_ns
    wide = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", depth=True, zmin_m=0.3, zmax_m=1.0,
                         calibration=cal)
    rep = run_batch([str(root / "a.png")], out, wide, workers=1)
    assert rep.done == [str(root / "a.png")] and (out / "a_refocus_0.5m.png").stat().st_mtime_ns == stamp
    assert read_manifest(out / "manifest.jsonl")[-1]["outputs"] == ["a_depth.tiff", "a_confidence.tiff",
                                                                    "a_depth_preview.png"]
    rec = json.loads((out / "a.lfring.json").read_text())
    assert rec["status"] == "done" and rec["planned_outputs"] == {} and len(rec["outputs"]) == 4
    assert all((out / rel).is_file() for rel in _listed_outputs(out))


def test_a_left_out_flat_field_lists_no_outputs(tmp_path):
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    copy_frame(data / "flat.png", root / "flat.png")
    out = tmp_path / "out"
    rep = run_batch([str(root)], out, BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add"), workers=1)
    assert rep.exit_code == 0 and [p for p, _ in rep.left_out] == [str(root / "flat.png")]
    (entry,) = read_manifest(out / "manifest.jsonl")
    assert entry["status"] == "left_out" and entry["outputs"] == []
    assert entry["planned_outputs"] == ["flat_refocus_0.5m.png"]
    assert entry["record"] is None  # it named flat.lfring.json, which no run writes
    assert sorted(p.name for p in out.iterdir()) == ["manifest.jsonl"]


def test_a_changed_sidecar_is_a_changed_input(frames, tmp_path, capsys):
    """A frame's sidecar edited (its Bayer pattern) after a run: the rerun said 'skipped
    (already done)' and kept the image read with the old pattern. The sidecar is part of the
    input: the rerun refuses, saying so, and --overwrite redoes the frame. A record written
    before sidecars were counted is judged on the frame alone (its rerun skips: it cannot tell)."""
    d, cal_path, _ = frames
    root = tmp_path / "in"
    copy_frame(d / "scene.png", root / "a.png")
    out = tmp_path / "out"
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=load_calibration(cal_path))
    assert run_batch([str(root)], out, settings, workers=1).exit_code == 0
    record = out / "a.lfring.json"
    assert json.loads(record.read_text())["input_identity"]["sidecar"] is not None
    before = (out / "a_refocus_0.5m.png").read_bytes()
    # As an earlier lfring wrote it: no sidecar in the identity.
    kept = record.read_text()
    rec = json.loads(kept)
    del rec["input_identity"]["sidecar"]
    record.write_text(json.dumps(rec))
    assert run_batch([str(root)], out, settings, workers=1).skipped == [str(root / "a.png")]
    record.write_text(kept)
    side = root / "a.png.json"
    meta = json.loads(side.read_text())
    meta["pattern"] = {"RGGB": "BGGR"}.get(meta["pattern"], "RGGB")
    side.write_text(json.dumps(meta))
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.skipped == [] and rep.failed == [str(root / "a.png")]
    assert "the input changed since (the frame or its sidecar)" in rep.errors[str(root / "a.png")]
    assert (out / "a_refocus_0.5m.png").read_bytes() == before
    rep = run_batch([str(root)], out, settings, workers=1, overwrite=True)
    assert rep.done == [str(root / "a.png")] and (out / "a_refocus_0.5m.png").read_bytes() != before


# -- 1. a manifest.jsonl the batch did not write --------------------------------------------------
def test_a_foreign_manifest_is_refused_and_replaced_only_with_overwrite(frames, tmp_path, capsys):
    d, _, bounded = frames
    out = tmp_path / "out"
    out.mkdir()
    foreign = '{"id": 1, "label": "cat"}\n{"id": 2, "label": "dog"}\n'
    (out / "manifest.jsonl").write_text(foreign)
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=load_calibration(bounded))
    with pytest.raises(InvalidInputError, match="is not a manifest of lfring batch"):
        run_batch([str(d / "scene.png")], out, settings, workers=1)
    args = ["batch", str(d / "scene.png"), "-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--calib",
            str(bounded), "--workers", "1", "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert str(out / "manifest.jsonl") in err and "--overwrite" in err and "another output folder" in err
    assert "Traceback" not in err and "overwrite=True" not in err
    assert (out / "manifest.jsonl").read_text() == foreign
    assert sorted(p.name for p in out.iterdir()) == ["manifest.jsonl"]  # nothing processed
    # Asked to: the file is replaced by the batch's own manifest, which later runs append to.
    assert main([*args, "--overwrite"]) == 0
    assert main(args) == 0
    entries = read_manifest(out / "manifest.jsonl")
    assert [e["status"] for e in entries] == ["done", "skipped"]
    # A manifest of the batch with a line cut short by a killed run is still the batch's own.
    with open(out / "manifest.jsonl", "a") as f:
        f.write('{"run": "x", "inp')
    assert main(args) == 0
    capsys.readouterr()


# -- 2. a rerun that adds --depth; --zmin/--zmax and --depth follow the other commands -------------
def test_adding_depth_with_the_calibration_s_range_keeps_the_refocused_images(frames, tmp_path, capsys):
    """The audit's rerun: depth-aware images made over the calibration's range (0.3..1.0 m)
    are what --zmin 0.3 --zmax 1.0 makes too, so adding --depth with that range computes only
    the depth map; another range would change them, and the refusal names it."""
    d, _, bounded = frames
    out = tmp_path / "b"
    args = ["batch", str(d / "scene.png"), "-o", str(out), "--refocus", "0.3,0.5", "--calib", str(bounded), "--workers",
            "1", "--no-progress"]
    assert main(args) == 0
    before = {z: (out / f"scene_refocus_{z}m.png").read_bytes() for z in ("0.3", "0.5")}
    stamps = {z: (out / f"scene_refocus_{z}m.png").stat().st_mtime_ns for z in ("0.3", "0.5")}
    capsys.readouterr()
    assert main([*args, "--depth", "--zmin", "0.3", "--zmax", "1.0"]) == 0
    assert "1 done" in capsys.readouterr().out
    assert {z: (out / f"scene_refocus_{z}m.png").stat().st_mtime_ns for z in ("0.3", "0.5")} == stamps
    assert read_manifest(out / "manifest.jsonl")[-1]["outputs"] == ["scene_depth.tiff", "scene_confidence.tiff",
                                                                    "scene_depth_preview.png"]
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert set(rec["outputs"]) == {"refocus_0.3m", "refocus_0.5m", "depth", "confidence", "depth_preview"}
    assert rec["info"]["depth_range_m"] == [0.3, 1.0]
    # Kept rightly: a fresh run with the new settings makes the same images.
    fresh = tmp_path / "fresh"
    assert main(["batch", str(d / "scene.png"), "-o", str(fresh), "--refocus", "0.3,0.5", "--depth", "--zmin", "0.3",
                 "--zmax", "1.0", "--calib", str(bounded), "--workers", "1", "--no-progress"]) == 0
    assert {z: (fresh / f"scene_refocus_{z}m.png").read_bytes() for z in ("0.3", "0.5")} == before
    # --depth without a range takes the calibration's, as lfring depth: all done already.
    assert main([*args, "--depth"]) == 0
    assert "0 done, 1 skipped" in capsys.readouterr().out
    # Another range would make other images: refused, naming the setting and the way on.
    assert main([*args, "--depth", "--zmin", "0.25", "--zmax", "1.0"]) == 1
    err = capsys.readouterr().err
    assert "--zmin (0.3 then, 0.25 now)" in err and "--overwrite" in err and "--zmax" not in err
    assert {z: (out / f"scene_refocus_{z}m.png").stat().st_mtime_ns for z in ("0.3", "0.5")} == stamps


def test_depth_defaults_to_the_range_of_lfring_depth(frames, tmp_path, capsys):
    """--depth alone estimates over lfring.focus.depth_aware.estimation_range, as lfring depth
    does: an optics calibration, open to infinity, ends where the views stop moving."""
    import tifffile

    from lfring.focus.depth_aware import estimation_range

    d, cal_path, _ = frames
    out = tmp_path / "b"
    assert main(["batch", str(d / "scene.png"), "-o", str(out), "--depth", "--depth-method", "local", "--calib",
                 str(cal_path), "--workers", "1", "--no-progress"]) == 0
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert rec["info"]["depth_range_m"] == list(estimation_range(load_calibration(cal_path)))
    assert main(["depth", str(d / "scene.png"), "--method", "local", "--calib", str(cal_path), "-o",
                 str(tmp_path / "single")]) == 0
    np.testing.assert_array_equal(tifffile.imread(out / "scene_depth.tiff"),
                                  tifffile.imread(tmp_path / "single" / "scene_depth.tiff"))
    capsys.readouterr()


def test_zmin_zmax_go_with_depth_aware_refocusing_as_in_lfring_refocus(frames, tmp_path, capsys):
    d, _, bounded = frames
    base = ["batch", str(d / "scene.png"), "--calib", str(bounded), "--workers", "1", "--no-progress"]
    # Accepted with depth-aware --refocus (its depth map's range); this one is too narrow for
    # any depth map, which the frame's error says in the batch's options.
    assert main([*base, "-o", str(tmp_path / "a"), "--refocus", "0.3", "--zmin", "0.3", "--zmax", "0.31"]) == 1
    err = capsys.readouterr().err
    assert "--zmin 0.3 .. --zmax 0.31 m is too narrow" in err and "--method local" not in err
    # A given range that is the calibration's makes the images no range makes.
    assert main([*base, "-o", str(tmp_path / "b"), "--refocus", "0.5", "--zmin", "0.3", "--zmax", "1.0"]) == 0
    assert main([*base, "-o", str(tmp_path / "c"), "--refocus", "0.5"]) == 0
    assert cv2.imread(str(tmp_path / "b" / "scene_refocus_0.5m.png")).tobytes() == \
        cv2.imread(str(tmp_path / "c" / "scene_refocus_0.5m.png")).tobytes()
    # Refused where nothing makes a depth map.
    assert main([*base, "-o", str(tmp_path / "d"), "--refocus", "0.5", "--method", "shift-and-add", "--zmin", "0.3"]) == 2
    assert "--zmin/--zmax go with --depth, --viewer or --refocus by --method depth-aware" in capsys.readouterr().err
    # The help says so, and that --depth has a default range.
    assert main(["batch", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "Depth map of every frame over --zmin..--zmax (default: the calibration's range, as lfring depth)" in text
    assert "the one --method depth-aware refocuses from" in text and "go with --depth or --viewer" not in text
    shutil.rmtree(tmp_path / "a", ignore_errors=True)


def test_keys_resolve_the_range_and_refusals_name_what_differs(frames):
    from lfring.batch import decide_resume

    _, _, bounded = frames
    cal = load_calibration(bounded)
    given = BatchSettings(refocus_m=(0.5,), depth=True, zmin_m=0.3, zmax_m=1.0, calibration=cal)
    default = BatchSettings(refocus_m=(0.5,), depth=True, calibration=cal)
    assert given.output_keys() == default.output_keys()
    assert default.depth_range_m() == (0.3, 1.0)
    # Records of earlier versions hold the range as given: still done.
    assert default.output_keys(resolved=False) != default.output_keys()
    planned = {"refocus_0.5m": "a_refocus_0.5m.png"}
    old = {"outputs": planned, "output_keys": {"refocus_0.5m": default.output_keys(resolved=False)["refocus_0.5m"]},
           "input_identity": {"size_bytes": 1}, "status": "done", "settings": default.describe()}
    keys = {"refocus_0.5m": default.output_keys()["refocus_0.5m"]}
    args = (planned, keys, old, {"size_bytes": 1}, {"a_refocus_0.5m.png"})
    assert decide_resume(*args, record_exists=True, overwrite=False).action == "refuse"
    alias = default.output_keys(resolved=False)
    assert decide_resume(*args, record_exists=True, overwrite=False, alias_keys=alias).action == "skip"
    # What differs, in a refusal's words.
    other = BatchSettings(refocus_m=(0.5,), aperture=0.5, zmax_m=0.9, calibration=cal)
    done = {**old, "output_keys": {"refocus_0.5m": keys["refocus_0.5m"]}}
    assert other.differences("refocus_0.5m", done) == ["the aperture (default then, 0.5 now)", "zmax_m (1 then, 0.9 now)"]
    d = decide_resume(planned, {"refocus_0.5m": other.output_keys()["refocus_0.5m"]}, done, {"size_bytes": 1},
                      {"a_refocus_0.5m.png"}, record_exists=True, overwrite=False,
                      explain=lambda kind, rec: other.differences(kind, rec))
    assert d.action == "refuse" and "zmax_m (1 then, 0.9 now)" in d.reason and "overwrite=True" in d.reason
    # A record whose settings did not make the output (a later run's) tells nothing.
    assert other.differences("refocus_0.5m", {**done, "output_keys": {"refocus_0.5m": "0123456789abcdef"}}) == []


def test_a_refusal_after_shift_and_add_names_the_method(tmp_path, capsys):
    """The audit's rerun on the command line: images made by --method shift-and-add, asked for
    by depth-aware refocusing with --depth-method; the refusal names the method as the first run
    gave it, and no depth setting (none made those images)."""
    from pathlib import Path

    frame = str(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png")
    base = ["batch", frame, "-o", str(tmp_path / "out"), "--workers", "1", "--no-progress"]
    assert main([*base, "--refocus", "0.5", "--method", "shift-and-add"]) == 0
    capsys.readouterr()
    assert main([*base, "--refocus", "0.5,0.7", "--depth-method", "local"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "made with other settings: the refocusing method (shift-and-add then, depth-aware now). Give" in err
    assert not any(w in err for w in ("default then", "--zmin", "--zmax", "depth method", "depth cost"))
    assert not (tmp_path / "out" / "scene_refocus_0.7m.png").exists()


def test_a_record_names_the_run_and_settings_that_made_each_output(tmp_path, capsys):
    """A rerun that adds an image with other settings keeps the earlier image: the record's
    'settings' are the later run's, so it names the run that made each output and keeps that
    run's settings; a refusal over the earlier image explains it by them."""
    from pathlib import Path

    frame = str(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png")
    out = tmp_path / "out"
    base = ["batch", frame, "-o", str(out), "--workers", "1", "--no-progress"]
    assert main([*base, "--refocus", "0.5", "--method", "shift-and-add"]) == 0
    first = json.loads((out / "scene.lfring.json").read_text())["run"]
    assert main([*base, "--refocus", "0.7", "--aperture", "2"]) == 0
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert rec["settings"]["refocus_method"] == "depth-aware" and rec["settings"]["aperture"] == 2.0
    assert rec["output_runs"] == {"refocus_0.5m": first, "refocus_0.7m": rec["run"]} and rec["run"] != first
    earlier = rec["earlier_settings"][first]
    assert earlier["refocus_method"] == "shift-and-add" and earlier["refocus_m"] == [0.5]
    capsys.readouterr()
    # Asked again with the later run's settings, the earlier image is refused by what made it.
    assert main([*base, "--refocus", "0.5", "--aperture", "2"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "the refocusing method (shift-and-add then, depth-aware now)" in err
    # A third run that adds an image keeps both earlier attributions.
    assert main([*base, "--refocus", "0.7,0.9", "--aperture", "2"]) == 0
    again = json.loads((out / "scene.lfring.json").read_text())
    assert again["output_runs"] == {**rec["output_runs"], "refocus_0.9m": again["run"]}
    assert again["earlier_settings"] == {first: earlier, rec["run"]: rec["settings"]}


def test_an_output_written_since_by_hand_is_not_taken_as_done(tmp_path, capsys):
    """A rerun meets an output that was changed after the batch wrote it: the frame is refused
    (not skipped as done, not overwritten), until --overwrite redoes it."""
    from pathlib import Path

    frame = str(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png")
    out = tmp_path / "out"
    base = ["batch", frame, "-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--workers", "1",
            "--no-progress"]
    assert main(base) == 0
    image = out / "scene_refocus_0.5m.png"
    good = image.read_bytes()
    assert main(base) == 0 and "1 skipped" in capsys.readouterr().out  # untouched: done
    image.write_bytes(b"edited")
    assert main(base) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "scene_refocus_0.5m.png exists and was written since lfring batch made it" in err and "--overwrite" in err
    assert image.read_bytes() == b"edited"
    assert main([*base, "--overwrite"]) == 0
    assert image.read_bytes() == good
    # An output kept by a rerun that did not make it keeps the identity its own run recorded: a
    # rerun in between does not take a file edited meanwhile for the one the batch wrote.
    image.write_bytes(b"edited again")
    other = [a if a != "0.5" else "0.7" for a in base]
    assert main(other) == 0
    assert main(base) == 1
    assert "scene_refocus_0.5m.png exists and was written since lfring batch made it" in " ".join(capsys.readouterr().err.split())


def test_a_copy_that_lost_its_times_is_the_same_input_and_the_same_outputs(tmp_path, capsys):
    """Inputs and outputs whose modification times changed but whose contents did not (a folder
    copied without keeping the times, a frame touched): the rerun skips the frame as done, where
    it refused it as a changed input. A change of content of the same size is still a change,
    of the input and of an output alike."""
    import os
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    copy_frame(data / "scene.png", root / "scene.png")
    out = tmp_path / "out"
    base = ["batch", str(root), "-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--workers", "1",
            "--no-progress"]
    assert main(base) == 0
    rec = json.loads((out / "scene.lfring.json").read_text())
    assert len(rec["input_identity"]["blake2b"]) == 32 and len(rec["input_identity"]["sidecar"]["blake2b"]) == 32
    assert all(len(v["blake2b"]) == 32 for v in rec["output_identity"].values())
    import hashlib  # the outputs' digests, taken from the bytes written, are the files' own

    assert all(v["blake2b"] == hashlib.blake2b((out / rel).read_bytes(), digest_size=16).hexdigest()
               for rel, v in rec["output_identity"].items())
    capsys.readouterr()

    def touch(path):
        st = path.stat()
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))

    for path in (root / "scene.png", root / "scene.png.json", out / "scene_refocus_0.5m.png"):
        touch(path)
    assert main(base) == 0
    assert "1 skipped" in capsys.readouterr().out
    # The same size, another content: the input changed.
    frame = root / "scene.png"
    raw = bytearray(frame.read_bytes())
    raw[-20] ^= 0xFF
    kept = frame.read_bytes()
    frame.write_bytes(bytes(raw))
    assert main(base) == 1
    assert "the input changed since" in " ".join(capsys.readouterr().err.split())
    frame.write_bytes(kept)
    touch(frame)
    assert main(base) == 0
    capsys.readouterr()
    # An output of the same size edited by hand is not the batch's.
    image = out / "scene_refocus_0.5m.png"
    edited = bytearray(image.read_bytes())
    edited[-20] ^= 0xFF
    image.write_bytes(bytes(edited))
    assert main(base) == 1
    assert "written since lfring batch made it" in " ".join(capsys.readouterr().err.split())


def test_a_frame_that_changes_while_it_is_processed_is_not_recorded_as_done(tmp_path, monkeypatch, capsys):
    """A frame still being written when the batch planned it (or replaced meanwhile) was
    processed as read, then recorded with the identity it had when planned: every later run
    refused it as changed. Its outputs are not written now and the frame fails, saying why; the
    rerun processes it as it is then."""
    from pathlib import Path

    import lfring.batch.run as batch_run

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    copy_frame(data / "scene.png", root / "a.png")
    whole = (root / "a.png").read_bytes()
    (root / "a.png").write_bytes(whole[: len(whole) // 2])  # still being written when planned
    real = batch_run.process_frame

    def finished_meanwhile(path, *args, **kwargs):
        Path(path).write_bytes(whole)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(batch_run, "process_frame", finished_meanwhile)
    out = tmp_path / "out"
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add")
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.failed == [str(root / "a.png")] and "changed or went after the run planned it" in rep.errors[str(root / "a.png")]
    assert not (out / "a_refocus_0.5m.png").exists()
    assert json.loads((out / "a.lfring.json").read_text())["status"] == "failed"
    monkeypatch.setattr(batch_run, "process_frame", real)
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.done == [str(root / "a.png")] and (out / "a_refocus_0.5m.png").exists()
    assert run_batch([str(root)], out, settings, workers=1).skipped == [str(root / "a.png")]


def test_a_frame_of_the_same_name_from_another_folder_is_named_as_such(tmp_path, capsys):
    """Two folders' a.png into one output folder: the second was refused as 'the input changed
    since'; it is another frame, and the refusal names the one that made the outputs."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    copy_frame(data / "scene.png", tmp_path / "d1" / "a.png")
    copy_frame(data / "part_good.png", tmp_path / "d2" / "a.png")
    out = tmp_path / "out"
    base = ["-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--workers", "1", "--no-progress"]
    assert main(["batch", str(tmp_path / "d1"), *base]) == 0
    capsys.readouterr()
    assert main(["batch", str(tmp_path / "d2"), *base]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"made from another frame ({tmp_path / 'd1' / 'a.png'}) of the same name" in err and "--overwrite" in err
    assert "changed since" not in err


def test_a_frame_replaced_after_planning_is_not_recorded_under_its_new_identity(tmp_path, monkeypatch):
    """A frame replaced between the run's plan and its submission: its identity was taken again
    at submission, so the check before writing compared the new file with itself, and the
    record listed the old frame's kept image under the new frame's identity. The planned
    identity now stays, and the frame fails."""
    from pathlib import Path

    import lfring.batch.run as batch_run

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    copy_frame(data / "scene.png", root / "a.png")
    out = tmp_path / "out"
    assert run_batch([str(root)], out, BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add"), workers=1).done
    real = batch_run.input_identity

    def replaced_after_planning(path, *, digest=False):
        ident = real(path, digest=digest)
        if not digest:  # the plan's look: the frame is replaced right after it
            Path(path).write_bytes((data / "part_good.png").read_bytes())
        return ident

    monkeypatch.setattr(batch_run, "input_identity", replaced_after_planning)
    rep = run_batch([str(root)], out, BatchSettings(refocus_m=(0.5, 1.0), refocus_method="shift-and-add"), workers=1)
    assert rep.failed == [str(root / "a.png")] and "changed or went after the run planned it" in rep.errors[str(root / "a.png")]
    rec = json.loads((out / "a.lfring.json").read_text())
    assert rec["status"] == "failed" and rec["input_identity"]["size_bytes"] == len((data / "scene.png").read_bytes())
    assert not (out / "a_refocus_1m.png").exists()
