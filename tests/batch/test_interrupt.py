"""`lfring batch` stopped by Ctrl-C or SIGTERM at any moment: it exits promptly with 130 (143 for
SIGTERM), prints no traceback, leaves no worker running and no partial file, and a rerun
completes."""

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import pytest
from batch_frames import copy_frame
from child_processes import default_sigint, handles_sigterm

TRIES = 20
FRAMES = 8
EXIT_WITHIN_S = 10.0


@pytest.fixture(scope="module")
def small_frames(tmp_path_factory):
    """Small frames of the twin (8 x 8 binned) and their calibration."""
    from lfring.calibration import RingCalibration
    from lfring.cli.main import main
    from lfring.optics import load_device

    d = tmp_path_factory.mktemp("small")
    for name, seed in (("scene", 3), ("part", 4)):
        preset = ["scene"] if name == "scene" else ["part", "--defects", "0.015"]
        assert main(["-q", "synth", *preset, "--binning", "8", "--noise", "low", "--seed", str(seed), "--name", name,
                     "-o", str(d / "render")]) == 0
    cal = d / "cal_binned8.json"
    RingCalibration.from_optics(load_device("prototype").binned(8)).save(cal)
    # Enough frames that a run lasts long enough to be stopped at a moment drawn within it.
    for i in range(FRAMES):
        copy_frame(d / "render" / ("scene.png" if i % 2 == 0 else "part.png"), d / "in" / f"f{i}.png")
    return d / "in", cal


def _children(pid: int) -> set[int]:
    """The live descendants of ``pid`` (Linux /proc)."""
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = {int(k) for k in (task / "children").read_text().split()}
            except (OSError, ValueError):
                continue
            todo.extend(kids - out)
            out |= kids
    return out



def _alive(pid: int) -> bool:
    try:
        state = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("State:"))
    except (OSError, StopIteration):
        return False
    return "Z" not in state.split()[1]



def _batch(inp, cal, out):
    return [sys.executable, "-m", "lfring", "batch", str(inp), "-o", str(out), "--calib", str(cal), "--refocus", "0.5",
            "--workers", "2", "--no-progress", "--interpolation", "linear"]


def _check_no_partial_output(out: Path, view_shape):
    assert not (out / ".lfring-batch.lock").exists()
    leftovers = [p for p in out.rglob("*") if ".lfring-tmp" in p.parts or ".part" in p.name]
    assert leftovers == []
    for png in out.rglob("*.png"):
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        assert img is not None and img.shape[:2] == tuple(view_shape), png  # a whole image
    for rec in out.rglob("*.lfring.json"):
        json.loads(rec.read_text())


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc to follow the workers")
def test_interrupted_batch_stops_cleanly_and_resumes(small_frames, tmp_path):
    from lfring.calibration import RingCalibration

    inp, cal = small_frames
    view_shape = RingCalibration.load(cal).layout.view_shape
    rng = random.Random(31)
    env = {**os.environ, "PYTHONWARNINGS": "error"}
    # How long a whole run takes here, from its handlers on: the stops come within it, however
    # fast the machine (a fixed window let a fast one finish a quarter of the runs first), and
    # within the shortest run seen since (with other tests running beside, the first run was
    # slower than later ones, and a third of these finished before their signal).
    whole = subprocess.Popen(_batch(inp, cal, tmp_path / "whole"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, start_new_session=True, env=env)
    while not handles_sigterm(whole.pid) and whole.poll() is None:
        time.sleep(0.005)
    t0 = time.monotonic()
    _, err = whole.communicate(timeout=300)
    span = time.monotonic() - t0
    assert whole.returncode == 0, err
    codes = []
    for i in range(TRIES):
        sig = signal.SIGINT if i % 2 == 0 else signal.SIGTERM
        to_group = i % 4 < 2  # a terminal's Ctrl-C (and `timeout`) signals the whole group; `kill PID` one process
        out = tmp_path / f"out{i}"
        proc = subprocess.Popen(_batch(inp, cal, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, env=env, preexec_fn=default_sigint)
        seen: set[int] = set()
        stop = threading.Event()

        def follow(pid=proc.pid, seen=seen, stop=stop):
            while not stop.is_set() and proc.poll() is None:
                seen.update(_children(pid))
                time.sleep(0.01)

        watcher = threading.Thread(target=follow)
        watcher.start()
        t0 = time.monotonic()
        while not handles_sigterm(proc.pid) and proc.poll() is None and time.monotonic() - t0 < 60:
            time.sleep(0.005)
        ready = time.monotonic()
        time.sleep(rng.uniform(0.0, 0.9 * span))
        sent = time.monotonic()
        if proc.poll() is None:
            (os.killpg if to_group else os.kill)(proc.pid, sig)
        try:
            _, err = proc.communicate(timeout=EXIT_WITHIN_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            pytest.fail(f"try {i}: still running {EXIT_WITHIN_S} s after {sig.name}")
        finally:
            stop.set()
            watcher.join()
        waited = time.monotonic() - sent
        codes.append(proc.returncode)
        if proc.returncode == 0:
            span = min(span, sent - ready)
        assert "Traceback" not in err and "Error" not in err.replace("lfring: error:", ""), f"try {i}:\n{err}"
        if proc.returncode != 0:  # it may have finished before the signal came
            assert proc.returncode == 128 + sig, f"try {i}: exit {proc.returncode} after {sig.name}:\n{err}"
            if out.exists():  # the batch had begun (a stop during the command's imports comes before)
                assert "the same command again goes on from there" in err, f"try {i}:\n{err}"
            assert waited < EXIT_WITHIN_S
        deadline = time.monotonic() + 3
        while any(_alive(p) for p in seen) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [p for p in seen if _alive(p)], f"try {i}: workers left running after {sig.name}"
        _check_no_partial_output(out, view_shape)
        if i % 10 == 9:  # the rerun completes what was cut short
            rerun = subprocess.run(_batch(inp, cal, out), capture_output=True, text=True, timeout=300)
            assert rerun.returncode == 0, rerun.stderr
            assert "0 failed" in rerun.stdout
            _check_no_partial_output(out, view_shape)
            assert sorted(p.name for p in out.glob("*_refocus_0.5m.png")) == sorted(f"f{k}_refocus_0.5m.png" for k in range(FRAMES))
    assert codes.count(0) <= TRIES // 4, f"too few runs were interrupted: {codes}"


@pytest.mark.parametrize("where", ["temporary folder", "lock"])
def test_a_stop_during_the_cleanup_waits_for_it(small_frames, tmp_path, monkeypatch, where):
    """Ctrl-C that comes while a run removes its temporary folder or its lock (as it ends, done or
    stopped) is delivered after: neither is left behind, and the run still stops as asked."""
    import shutil

    import lfring.batch.record
    import lfring.batch.run
    from lfring.calibration import RingCalibration
    from lfring.batch import BatchSettings, run_batch

    inp, cal = small_frames
    out = tmp_path / "out"
    if where == "temporary folder":
        module, name, real = lfring.batch.run.shutil, "rmtree", shutil.rmtree
    else:
        module, name, real = lfring.batch.record.Path, "unlink", Path.unlink
    came = []

    def cut(path, *args, **kwargs):
        if not came and Path(path).name in (".lfring-tmp", ".lfring-batch.lock"):
            came.append(True)
            signal.raise_signal(signal.SIGINT)
        return real(path, *args, **kwargs)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        monkeypatch.setattr(module, name, cut)
        settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=RingCalibration.load(cal))
        with pytest.raises(KeyboardInterrupt):
            run_batch([str(inp / "f0.png")], out, settings, workers=1, progress=False)
    finally:
        monkeypatch.undo()
        signal.signal(signal.SIGINT, previous)
    assert came == [True]
    assert not (out / ".lfring-batch.lock").exists() and not (out / ".lfring-tmp").exists()
    assert (out / "f0_refocus_0.5m.png").exists()  # the frame was done before the stop came
