"""lfring.batch.record: resume (a pure decision, then whole runs that are cut short, rerun or
find files they did not make)."""

import json
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from batch_frames import copy_frame, load_calibration, render_frames

from lfring.batch import BatchSettings, read_manifest, run_batch


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


def test_killed_run_leaves_no_partial_output_and_resumes(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    for i in range(12):
        copy_frame(d / "scene.png", root / f"k{i:02d}.png")
    out = tmp_path / "out"
    # What is judged is the kill and the resume, not the refocusing method: shift-and-add.
    args = ["batch", str(root), "-o", str(out), "--refocus", "0.4,0.6", "--method", "shift-and-add", "--calib", str(cal_path),
            "--workers", "1", "--no-progress"]
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
    rep = run_batch([str(root)], out, BatchSettings(refocus_m=(0.4, 0.6), refocus_method="shift-and-add",
                                                  calibration=load_calibration(cal_path), calibration_name=str(cal_path)),
                    workers=1)
    assert rep.exit_code == 0 and len(rep.done) + len(rep.skipped) == 12 and len(rep.skipped) >= done
    assert not (out / ".lfring-tmp").exists() and not (out / ".lfring-batch.lock").exists()
    ref = cv2.imread(str(out / "k00_refocus_0.4m.png"))
    for i in range(12):
        np.testing.assert_array_equal(cv2.imread(str(out / f"k{i:02d}_refocus_0.4m.png")), ref)


def test_never_replaces_files_it_did_not_make(frames, tmp_path):
    d, cal_path = frames
    root = tmp_path / "in"
    copy_frame(d / "scene.png", root / "a.png")
    copy_frame(d / "scene.png", root / "b.png")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a_refocus_0.5m.png").write_bytes(b"somebody else's file")
    settings = BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path))
    rep = run_batch([str(root)], out, settings, workers=1)
    assert rep.failed == [str(root / "a.png")] and rep.done == [str(root / "b.png")]
    assert "not made by lfring batch" in rep.errors[str(root / "a.png")]
    assert (out / "a_refocus_0.5m.png").read_bytes() == b"somebody else's file"
    # Other settings for the same names: refused, then replaced with overwrite.
    other = BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path), interpolation="cubic")
    rep = run_batch([str(root / "b.png")], out, other, workers=1)
    assert rep.failed == [str(root / "b.png")] and "other settings" in rep.errors[str(root / "b.png")]
    rep = run_batch([str(root)], out, other, workers=1, overwrite=True)
    assert rep.exit_code == 0 and len(rep.done) == 2
    assert cv2.imread(str(out / "a_refocus_0.5m.png")) is not None
    # A changed input is not silently skipped either.
    copy_frame(d / "part.png", root / "b.png")
    rep = run_batch([str(root / "b.png")], out, other, workers=1)
    assert rep.failed and "input changed" in rep.errors[str(root / "b.png")]


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


def test_a_manifest_line_cut_short_by_a_full_disk_is_taken_back_and_named(tmp_path):
    """A full disk (here a file-size limit) cut a manifest line short and the error named no
    file; the next run's first line was glued onto the cut one, and a reader lost both. The
    cut line is taken back, the error names the manifest, and a line an earlier run left
    without its end no longer swallows the next one."""
    import subprocess
    import sys

    from lfring.batch.record import append_manifest, read_manifest

    path = tmp_path / "manifest.jsonl"
    append_manifest(path, {"run": "r1", "input": "a.png", "status": "done"})
    before = path.read_bytes()
    child = ("import resource, sys\n"
             "from pathlib import Path\n"
             "from lfring.batch.record import append_manifest\n"
             f"resource.setrlimit(resource.RLIMIT_FSIZE, ({len(before) + 10}, resource.RLIM_INFINITY))\n"
             "try:\n"
             f"    append_manifest(Path({str(path)!r}), {{'run': 'r2', 'input': 'b.png', 'status': 'done'}})\n"
             "except OSError as exc:\n"
             "    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=120)
    assert f"cannot append to {path}" in out.stdout, out.stderr
    assert path.read_bytes() == before
    with open(path, "ab") as f:  # a run killed in the middle of a line
        f.write(b'{"run": "x", "inp')
    append_manifest(path, {"run": "r3", "input": "c.png", "status": "done"})
    assert [e["input"] for e in read_manifest(path)] == ["a.png", "c.png"]
