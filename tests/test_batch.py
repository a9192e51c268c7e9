"""lfring.batch and `lfring batch`: error isolation, resume, atomic outputs, Dask."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring.batch import (
    BatchSettings,
    find_inputs,
    plan_jobs,
    process_frame,
    read_manifest,
    run_batch,
)
from lfring.cli.main import main
from lfring.errors import InvalidInputError

N_FRAMES = 50
CORRUPT = ("bad_truncated.png", "sub/bad_empty.png", "sub/deeper/bad_garbage.tif")


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    from lfring.calibration import RingCalibration
    from lfring.optics import load_device

    d = tmp_path_factory.mktemp("render")
    for name, seed in (("scene", 3), ("part", 4)):
        preset = ["scene"] if name == "scene" else ["part", "--defects", "0.015"]
        assert main(["-q", "synth", *preset, "--binning", "4", "--noise", "low", "--seed", str(seed), "--name", name,
                     "-o", str(d)]) == 0
    cal_path = d / "cal_binned4.json"
    RingCalibration.from_optics(load_device("prototype").binned(4)).save(cal_path)
    return d, cal_path


def _copy_frame(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)
    shutil.copyfile(str(src) + ".json", str(dst) + ".json")


@pytest.fixture
def folder(frames, tmp_path):
    """50 frames in nested folders, 3 of them corrupt."""
    d, _ = frames
    root = tmp_path / "in"
    good = [f"f{i:02d}.png" if i < 20 else f"sub/f{i:02d}.png" if i < 40 else f"sub/deeper/f{i:02d}.png"
            for i in range(N_FRAMES - len(CORRUPT))]
    for i, rel in enumerate(good):
        _copy_frame(d / ("scene.png" if i % 2 == 0 else "part.png"), root / rel)
    data = (d / "scene.png").read_bytes()
    (root / CORRUPT[0]).write_bytes(data[: len(data) // 2])
    shutil.copyfile(d / "scene.png.json", root / (CORRUPT[0] + ".json"))
    (root / CORRUPT[1]).write_bytes(b"")
    shutil.copyfile(d / "scene.png.json", root / (CORRUPT[1] + ".json"))
    (root / CORRUPT[2]).write_bytes(b"this is not a TIFF file\n" * 10)
    return root, good


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _expected_refocus(frame: Path, cal_path: Path, depth_m: float) -> np.ndarray:
    from lfring import RingCalibration, demosaic, load_raw, split_views
    from lfring.io.writers import encode_image
    from lfring.focus import refocus

    cal = RingCalibration.load(cal_path)
    views = split_views(demosaic(load_raw(frame)), cal.layout)
    from lfring.core.warping import DEFAULT_INTERPOLATION

    return encode_image(refocus(views, cal, depth_m, interpolation=DEFAULT_INTERPOLATION), 8, "srgb")


def test_fifty_frames_three_corrupt_then_resume(frames, folder, tmp_path):
    d, cal_path = frames
    root, good = folder
    before = _digest(root)
    out = tmp_path / "out"
    from lfring import RingCalibration

    settings = BatchSettings(refocus_m=(0.5,), calibration=RingCalibration.load(cal_path), calibration_name="binned4")
    rep = run_batch([str(root)], out, settings, workers=2)
    # Exactly the three corrupt frames fail, by name; the 47 others are done.
    assert sorted(rep.failed) == sorted(str(root / c) for c in CORRUPT)
    assert len(rep.done) == N_FRAMES - 3 and rep.skipped == [] and rep.exit_code == 1
    for c in CORRUPT:
        assert str(root / c) in rep.errors[str(root / c)]  # the message names the file
    # Outputs keep the folder structure, and are exactly what refocus gives.
    for rel in good:
        assert (out / rel.replace(".png", "_refocus_0.5m.png")).is_file()
        rec = json.loads((out / rel.replace(".png", ".lfring.json")).read_text())
        assert rec["status"] == "done" and rec["settings"]["refocus_m"] == [0.5]
    img = cv2.cvtColor(cv2.imread(str(out / "sub/f21_refocus_0.5m.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, _expected_refocus(d / "part.png", cal_path, 0.5))
    # One manifest line per frame, with status, outputs and timings.
    entries = read_manifest(out / "manifest.jsonl")
    assert len(entries) == N_FRAMES
    assert sorted(e["input"] for e in entries if e["status"] == "failed") == sorted(rep.failed)
    assert all(e["timings_s"]["total"] > 0 for e in entries if e["status"] == "done")
    assert not (out / ".lfring-tmp").exists() and not (out / ".lfring-batch.lock").exists()
    # Inputs untouched.
    assert _digest(root) == before

    # A rerun skips the 47 done (their files untouched) and tries the 3 corrupt ones again.
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    rep2 = run_batch([str(root)], out, settings, workers=1)
    assert len(rep2.skipped) == N_FRAMES - 3 and rep2.done == [] and sorted(rep2.failed) == sorted(rep.failed)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.png")} == stamp
    assert len(read_manifest(out / "manifest.jsonl")) == 2 * N_FRAMES


def test_cli_batch_names_failures_and_exits_1(frames, folder, tmp_path, capsys):
    _, cal_path = frames
    root, _ = folder
    out = tmp_path / "out"
    code = main(["batch", str(root), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers", "1",
                 "--interpolation", "linear", "--no-progress"])
    assert code == 1
    captured = capsys.readouterr()
    # Each failure is printed once, as it happens: "lfring: ERROR: PATH: why".
    failed = [line for line in captured.err.splitlines() if line.startswith("lfring: ERROR: ")]
    assert sorted(line.split(": ")[2] for line in failed) == sorted(str(root / c) for c in CORRUPT)
    for c in CORRUPT:
        assert captured.err.count(str(root / c)) == 1
    assert f"{N_FRAMES} frames: {N_FRAMES - 3} done, 0 skipped (already done), 3 failed" in captured.out
    # Rerun: all good frames skipped, exit 1 again for the corrupt ones.
    assert main(["batch", str(root), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers", "1",
                 "--interpolation", "linear", "--no-progress"]) == 1
    assert f"0 done, {N_FRAMES - 3} skipped" in capsys.readouterr().out


def test_killed_run_leaves_no_partial_output_and_resumes(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    for i in range(12):
        _copy_frame(d / "scene.png", root / f"k{i:02d}.png")
    out = tmp_path / "out"
    args = ["batch", str(root), "-o", str(out), "--refocus", "0.4,0.6", "--calib", str(cal_path), "--workers", "1",
            "--no-progress"]
    proc = subprocess.Popen([sys.executable, "-c", f"from lfring.cli.main import main; raise SystemExit(main({args!r}))"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            m = out / "manifest.jsonl"
            if m.exists() and sum(e["status"] == "done" for e in read_manifest(m)) >= 3:
                break
            assert proc.poll() is None, "the batch ended before it could be killed"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    done = sum(e["status"] == "done" for e in read_manifest(out / "manifest.jsonl"))
    assert 3 <= done < 12
    # Every visible file is complete: images decode whole, records parse.
    visible = [p for p in out.rglob("*") if p.is_file() and not any(part.startswith(".") for part in p.relative_to(out).parts)]
    for p in visible:
        if p.suffix == ".png":
            assert cv2.imread(str(p)) is not None, p
        elif p.name.endswith(".lfring.json"):
            assert json.loads(p.read_text())["status"] in ("pending", "done")
    # The rerun finishes the job without --overwrite, and cleans what the killed run left.
    rep = run_batch([str(root)], out, BatchSettings(refocus_m=(0.4, 0.6), calibration=_load(cal_path), calibration_name=str(cal_path)),
                    workers=1)
    assert rep.exit_code == 0 and len(rep.done) + len(rep.skipped) == 12 and len(rep.skipped) >= done
    assert not (out / ".lfring-tmp").exists() and not (out / ".lfring-batch.lock").exists()
    ref = cv2.imread(str(out / "k00_refocus_0.4m.png"))
    for i in range(12):
        np.testing.assert_array_equal(cv2.imread(str(out / f"k{i:02d}_refocus_0.4m.png")), ref)


def _load(p):
    from lfring import RingCalibration

    return RingCalibration.load(p)


def test_never_replaces_files_it_did_not_make(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    _copy_frame(d / "scene.png", root / "a.png")
    _copy_frame(d / "scene.png", root / "b.png")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a_refocus_0.5m.png").write_bytes(b"somebody else's file")
    settings = BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path))
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.failed == [str(root / "a.png")] and rep.done == [str(root / "b.png")]
    assert "not made by lfring batch" in rep.errors[str(root / "a.png")]
    assert (out / "a_refocus_0.5m.png").read_bytes() == b"somebody else's file"
    # Other settings for the same names: refused, then replaced with overwrite.
    other = BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path), interpolation="cubic")
    rep = run_batch([str(root / "b.png")], out, other, workers=1)
    assert rep.failed == [str(root / "b.png")] and "other settings" in rep.errors[str(root / "b.png")]
    rep = run_batch([str(root)], out, other, workers=1, overwrite=True)
    assert rep.exit_code == 0 and len(rep.done) == 2
    assert cv2.imread(str(out / "a_refocus_0.5m.png")) is not None
    # A changed input is not silently skipped either.
    _copy_frame(d / "part.png", root / "b.png")
    rep = run_batch([str(root / "b.png")], out, other, workers=1)
    assert rep.failed and "input changed" in rep.errors[str(root / "b.png")]


def test_inputs_outputs_and_names(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    _copy_frame(d / "scene.png", root / "a.png")
    shutil.copyfile(d / "scene.png", root / "a.tif")
    (root / ".hidden.png").write_bytes(b"x")
    (root / "notes.txt").write_text("not a frame")
    settings = BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path))
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


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({}, "nothing to do"),
        ({"refocus_m": (0.0,)}, "positive"),
        ({"refocus_m": (0.5, 0.5)}, "repeat"),
        ({"depth": True}, "zmin_m and zmax_m"),
        ({"depth": True, "zmin_m": 0.8, "zmax_m": 0.4}, "smaller"),
        ({"refocus_m": (0.5,), "bit_depth": 12}, "bit_depth"),
        ({"refocus_m": (0.5,), "planes": 1}, "planes"),
        # Two planes leave the semi-global depth nothing to judge its answers against: the
        # batch's own depth map or the viewer's.
        ({"depth": True, "zmin_m": 0.3, "zmax_m": 1.0, "planes": 2}, "planes must be an integer >= 3"),
        ({"viewer": True, "planes": 2}, "planes must be an integer >= 3"),
    ],
)
def test_settings_errors(kwargs, text):
    with pytest.raises(InvalidInputError, match=text):
        BatchSettings(**kwargs)


@pytest.mark.parametrize(
    "args, text",
    [
        ([], "nothing to do"),
        (["--refocus", "0.5", "--zmin", "0.3"], "go with --depth"),
        (["--depth"], "--zmin and --zmax"),
        (["--refocus", "0.5", "--workers", "0"], "workers"),
        (["--refocus", "abc"], "comma-separated"),
        (["--refocus", "0.5", "--reference", "7"], "reference"),
    ],
)
def test_cli_usage_errors_exit_2(frames, tmp_path, capsys, args, text):
    d, cal_path = frames
    assert main(["batch", str(d / "scene.png"), "-o", str(tmp_path / "o"), "--calib", str(cal_path), *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
    assert main(["batch", str(tmp_path / "nothing_here"), "-o", str(tmp_path / "o"), "--refocus", "0.5"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_depth_and_all_in_focus_outputs(frames, tmp_path):
    import tifffile

    d, cal_path = frames
    out = tmp_path / "out"
    settings = BatchSettings(depth=True, zmin_m=0.25, zmax_m=1.2, all_in_focus=True, calibration=_load(cal_path),
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

    cal = _load(cal_path)
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


def test_dask_cluster_on_loopback_matches_local(frames, tmp_path):
    import distributed  # the README's install includes the dask extra
    d, cal_path = frames
    root = tmp_path / "in"
    for i in range(4):
        _copy_frame(d / ("scene.png" if i % 2 else "part.png"), root / f"d{i}.png")
    (root / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    settings = BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path))
    local = run_batch([str(root)], tmp_path / "local", settings, workers=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as cluster:
        rep = run_batch([str(root)], tmp_path / "dask", settings, executor="dask", scheduler=cluster.scheduler_address)
    assert rep.failed == [str(root / "broken.png")] == local.failed and len(rep.done) == 4
    workers = {e.get("worker") for e in read_manifest(tmp_path / "dask" / "manifest.jsonl") if e["status"] == "done"}
    assert os.getpid() not in {int(w.split(":")[1]) for w in workers}  # computed in the cluster's processes
    for i in range(4):
        a = (tmp_path / "local" / f"d{i}_refocus_0.5m.png").read_bytes()
        assert (tmp_path / "dask" / f"d{i}_refocus_0.5m.png").read_bytes() == a


def test_dask_missing_says_how_to_install(frames, tmp_path, monkeypatch):
    d, cal_path = frames
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InvalidInputError, match=r"pip install"):
        run_batch([str(d / "scene.png")], tmp_path / "o", BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path)),
                  executor="dask")
    assert not (tmp_path / "o" / "scene_refocus_0.5m.png").exists()


def test_progress_bar_shows_rate_and_eta(frames, tmp_path, capsys):
    d, cal_path = frames
    rep = run_batch([str(d / "scene.png"), str(d / "part.png")], tmp_path / "o",
                    BatchSettings(refocus_m=(0.5,), calibration=_load(cal_path)), workers=1, progress=True)
    assert rep.exit_code == 0
    err = capsys.readouterr().err
    assert "lfring batch" in err and "2/2" in err and "frame/s" in err and "<00:00" in err


# -- the resume decision (a pure function) -------------------------------------------------------
def _decide(planned, keys, record, existing, *, identity=None, overwrite=False, record_exists=None, settings_key=""):
    from lfring.batch import decide_resume

    identity = identity or {"size_bytes": 10, "mtime_ns": 1}
    return decide_resume(planned, keys, record, identity, set(existing),
                         record_exists=record is not None if record_exists is None else record_exists,
                         overwrite=overwrite, settings_key=settings_key)


P5, P7 = {"refocus_0.5m": "a_refocus_0.5m.png"}, {"refocus_0.7m": "a_refocus_0.7m.png"}
K5, K7 = {"refocus_0.5m": "k5"}, {"refocus_0.7m": "k7"}
SAME = {"size_bytes": 10, "mtime_ns": 1}


def _record(outputs, keys, status="done", identity=SAME, pending=None):
    return {"outputs": outputs, "output_keys": keys if status == "done" else {}, "pending_keys": pending or {},
            "input_identity": identity, "status": status}


def test_resume_fresh_and_foreign_files():
    assert _decide(P5, K5, None, []).action == "run"
    d = _decide(P5, K5, None, ["a_refocus_0.5m.png"])
    assert d.action == "refuse" and "not made by lfring batch" in d.reason
    assert _decide(P5, K5, None, [], record_exists=True).action == "refuse"
    assert _decide(P5, K5, None, ["a_refocus_0.5m.png"], overwrite=True).kinds == ("refocus_0.5m",)


def test_resume_skips_done_and_computes_only_what_is_added():
    rec = _record(P5, K5)
    assert _decide(P5, K5, rec, ["a_refocus_0.5m.png"]).action == "skip"
    d = _decide({**P5, **P7}, {**K5, **K7}, rec, ["a_refocus_0.5m.png"])
    assert (d.action, d.kinds) == ("run", ("refocus_0.7m",))
    # A done output deleted by hand is made again, alone.
    assert _decide(P5, K5, rec, []).kinds == ("refocus_0.5m",)


def test_resume_refuses_other_settings_and_changed_inputs():
    rec = _record(P5, {"refocus_0.5m": "linear"})
    d = _decide(P5, K5, rec, ["a_refocus_0.5m.png"])
    assert d.action == "refuse" and "other settings" in d.reason
    d = _decide(P5, K5, _record(P5, K5, identity={"size_bytes": 11, "mtime_ns": 2}), ["a_refocus_0.5m.png"])
    assert d.action == "refuse" and "input changed" in d.reason
    assert _decide(P5, K5, _record(P5, K5, identity={"size_bytes": 11}), []).action == "run"


def test_depth_keys_follow_the_default_depth_cost(monkeypatch):
    """A semi-global depth map made with another default cost (the 'lcn' of earlier versions) has
    another key, so a resumed folder refuses it as made with other settings; the refocused
    images and the local sweep's maps keep theirs."""
    import dataclasses

    from lfring.depth.engines import ENGINES

    kw = dict(refocus_m=(0.5,), depth=True, zmin_m=0.3, zmax_m=1.0)
    settings = {m: BatchSettings(**kw, depth_method=m) for m in ("sgm", "local")}
    now = {m: s.output_keys() for m, s in settings.items()}
    monkeypatch.setitem(ENGINES._entries, "sgm", dataclasses.replace(ENGINES["sgm"], default_cost="lcn"))
    before = {m: BatchSettings(**kw, depth_method=m).output_keys() for m in settings}
    for kind in ("depth", "confidence", "depth_preview"):
        assert now["sgm"][kind] != before["sgm"][kind]
        assert now["local"][kind] == before["local"][kind]
    assert now["sgm"]["refocus_0.5m"] == before["sgm"]["refocus_0.5m"]
    rec = _record({"depth": "a_depth.tiff"}, {"depth": before["sgm"]["depth"]})
    d = _decide({"depth": "a_depth.tiff"}, {"depth": now["sgm"]["depth"]}, rec, ["a_depth.tiff"])
    assert d.action == "refuse" and "other settings" in d.reason


def test_resume_replaces_files_of_its_own_cut_short_run():
    rec = _record(P5, {}, status="pending", pending=K5)
    assert _decide(P5, K5, rec, ["a_refocus_0.5m.png"]).kinds == ("refocus_0.5m",)
    rec = _record(P5, {}, status="pending", pending={"refocus_0.5m": "other"})
    assert _decide(P5, K5, rec, ["a_refocus_0.5m.png"]).action == "refuse"


def test_resume_reads_records_from_before_output_keys():
    old = {"outputs": P5, "settings_key": "s1", "input_identity": SAME, "status": "done"}
    assert _decide(P5, K5, old, ["a_refocus_0.5m.png"], settings_key="s1").action == "skip"
    assert _decide(P5, K5, old, ["a_refocus_0.5m.png"], settings_key="s2").action == "refuse"


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


def test_legacy_key_is_the_key_of_records_before_output_keys():
    # 6e76e9ced5695793 is what BatchSettings(refocus_m=(0.5,)).key() returned before per-output
    # keys (commit 188722c): folders made then resume instead of being refused.
    # (its default interpolation was cubic then).
    assert BatchSettings(refocus_m=(0.5,), interpolation="cubic").legacy_key() == "6e76e9ced5695793"
    assert BatchSettings(refocus_m=(0.5,), pattern="RGGB").legacy_key() is None
