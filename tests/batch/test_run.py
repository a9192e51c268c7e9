"""lfring.batch.run: a whole folder with corrupt frames, then its resume; the progress bar."""

import json
import os

import cv2
import numpy as np
import pytest
from batch_frames import (
    CORRUPT,
    copy_frame,
    N_FRAMES,
    digest,
    expected_refocus,
    load_calibration,
    make_folder,
    render_frames,
)

from lfring.batch import BatchSettings, read_manifest, run_batch


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


@pytest.fixture
def folder(frames, tmp_path):
    """50 frames in nested folders, 3 of them corrupt."""
    d, _ = frames
    return make_folder(d, tmp_path / "in")


def test_fifty_frames_three_corrupt_then_resume(frames, folder, tmp_path):
    d, cal_path = frames
    root, good = folder
    before = digest(root)
    out = tmp_path / "out"
    from lfring import RingCalibration

    # Shift-and-add: what is judged here is the batch around each frame (failures, records, resume),
    # not the method; the default method's batch is judged in test_cli_batch.py.
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=RingCalibration.load(cal_path),
                             calibration_name="binned4")
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
        assert rec["settings"]["refocus_method"] == "shift-and-add"
    img = cv2.cvtColor(cv2.imread(str(out / "sub/f21_refocus_0.5m.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, expected_refocus(d / "part.png", cal_path, 0.5, method="shift-and-add"))
    # One manifest line per frame, with status, outputs and timings.
    entries = read_manifest(out / "manifest.jsonl")
    assert len(entries) == N_FRAMES
    assert sorted(e["input"] for e in entries if e["status"] == "failed") == sorted(rep.failed)
    assert all(e["timings_s"]["total"] > 0 for e in entries if e["status"] == "done")
    assert not (out / ".lfring-tmp").exists() and not (out / ".lfring-batch.lock").exists()
    # Inputs untouched.
    assert digest(root) == before

    # A rerun skips the 47 done (their files untouched) and tries the 3 corrupt ones again.
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    rep2 = run_batch([str(root)], out, settings, workers=1)
    assert len(rep2.skipped) == N_FRAMES - 3 and rep2.done == [] and sorted(rep2.failed) == sorted(rep.failed)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.png")} == stamp
    assert len(read_manifest(out / "manifest.jsonl")) == 2 * N_FRAMES


def test_progress_bar_shows_rate_and_eta(frames, tmp_path, capsys):
    d, cal_path = frames
    rep = run_batch([str(d / "scene.png"), str(d / "part.png")], tmp_path / "o",
                    BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path)), workers=1, progress=True)
    assert rep.exit_code == 0
    err = capsys.readouterr().err
    assert "lfring batch" in err and "2/2" in err and "frame/s" in err and "<00:00" in err


def test_a_lost_worker_s_frames_run_again_one_at_a_time_and_only_the_culprit_fails(tmp_path, monkeypatch):
    """A worker killed (the OOM killer) breaks its pool and every frame in it: the frame read
    first was blamed (an innocent one, as often as not, failed after a second loss), and a
    broken pool used again ended the run in a BrokenProcessPool traceback. The frames the pool
    held now run again one at a time in a pool of one worker: the frame that kills its worker
    there fails, the others are done, and every frame has its record and manifest line."""
    from concurrent.futures import Future
    from concurrent.futures.process import BrokenProcessPool
    from pathlib import Path

    import lfring.batch.run as batch_run

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    for name in ("a", "b", "c", "doomed", "e", "f"):
        copy_frame(data / "scene.png", root / f"{name}.png")
    pools = []

    class Killed:
        """A pool in this process, as a ProcessPoolExecutor behaves: the frames submitted run when
        waited for; one that kills its worker ('doomed') breaks the pool, and every frame it
        held fails with it, as does every later submission."""

        def __init__(self, workers=1):
            self.workers, self.held, self.broken = workers, [], False
            pools.append(self)

        def submit(self, fn, path, *args):
            if self.broken:
                raise BrokenProcessPool("a child process terminated abruptly")
            fut = Future()
            self.held.append((fut, fn, path, args))
            return fut

        def run(self):
            if any(Path(path).stem == "doomed" for _, _, path, _ in self.held):
                self.broken = True
                for fut, *_ in self.held:
                    fut.set_exception(BrokenProcessPool("a child process terminated abruptly"))
            else:
                for fut, fn, path, args in self.held:
                    fut.set_result(fn(path, *args))
            self.held = []

        def shutdown(self, wait=True, cancel_futures=False):
            pass

        def terminate(self):
            pass

        def wait(self, fs, return_when=None):
            return waited(fs, return_when)

    def waited(fs, return_when=None):
        for pool in pools:
            pool.run()
        return set(fs), set()

    monkeypatch.setattr(batch_run, "local_executor", lambda workers: (Killed(workers), waited))
    monkeypatch.setattr(batch_run, "LocalPool", Killed)
    out = tmp_path / "out"
    rep = run_batch([str(root)], out, BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add"), workers=2)
    assert sorted(Path(p).stem for p in rep.done) == ["a", "b", "c", "e", "f"]
    assert [Path(p).stem for p in rep.failed] == ["doomed"]
    assert "the worker processing it was lost" in rep.errors[str(root / "doomed.png")]
    entries = {Path(e["input"]).stem: e["status"] for e in read_manifest(out / "manifest.jsonl")}
    assert entries == {"a": "done", "b": "done", "c": "done", "doomed": "failed", "e": "done", "f": "done"}
    assert json.loads((out / "doomed.lfring.json").read_text())["status"] == "failed"
    assert any(p.workers == 1 for p in pools[1:])  # the suspects ran in a pool of one


def test_a_reader_s_note_names_the_frame_once(tmp_path, monkeypatch, caplog):
    """The reader's notes start with the frame's path; the batch put it before them again
    ('late/sb.png: late/sb.png: levels assumed ...'). A note that does not name it gets it."""
    import logging
    from pathlib import Path

    import lfring.batch.run as batch_run

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    root = tmp_path / "in"
    copy_frame(data / "scene.png", root / "sb.png")
    real = batch_run.process_frame

    def noted(path, *args, **kwargs):
        res = real(path, *args, **kwargs)
        res.info.setdefault("warnings", []).extend([f"{path}: levels assumed (black 0)", "a note of its own",
                                                    f"{os.path.abspath(path)}: as a cluster's worker names it"])
        return res

    monkeypatch.setattr(batch_run, "process_frame", noted)
    monkeypatch.chdir(tmp_path)  # a relative input: a cluster's worker names it by its absolute path
    with caplog.at_level(logging.WARNING, logger="lfring.batch"):
        rep = run_batch(["in"], tmp_path / "out", BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add"),
                        workers=1)
    frame = os.path.join("in", "sb.png")
    assert rep.done == [frame]
    assert f"{frame}: levels assumed (black 0)" in caplog.text and f"{frame}: {frame}:" not in caplog.text
    assert f"{frame}: a note of its own" in caplog.text
    assert f"{frame}: {os.path.abspath(frame)}:" not in caplog.text and f"{os.path.abspath(frame)}: as a cluster's" in caplog.text
