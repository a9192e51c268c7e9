"""lfring.batch.executors: a Dask cluster gives what the local executor gives, and says how to
install it when it is missing."""

import os
import signal
import sys

import pytest
from batch_frames import copy_frame, load_calibration, render_frames

from lfring.batch import BatchSettings, read_manifest, run_batch
from lfring.errors import InvalidInputError


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


def test_dask_cluster_on_loopback_matches_local(frames, tmp_path):
    import distributed  # the README's install includes the dask extra
    d, cal_path = frames
    root = tmp_path / "in"
    for i in range(4):
        copy_frame(d / ("scene.png" if i % 2 else "part.png"), root / f"d{i}.png")
    (root / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    settings = BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path))
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


def test_dask_workers_find_inputs_given_by_relative_paths(frames, tmp_path, monkeypatch):
    """A cluster's workers run in their own working folder: an input given as in/scene.png failed
    there with 'no such file', though the same path named it on the same file system."""
    import distributed

    d, cal_path = frames
    copy_frame(d / "scene.png", tmp_path / "in" / "a.png")
    settings = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", calibration=load_calibration(cal_path))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as cluster:
        monkeypatch.chdir(tmp_path)  # the workers started elsewhere
        rep = run_batch(["in"], "out", settings, executor="dask", scheduler=cluster.scheduler_address)
    assert rep.failed == [] and rep.done == [os.path.join("in", "a.png")], rep.errors
    assert (tmp_path / "out" / "a_refocus_0.5m.png").exists()


def test_dask_missing_says_how_to_install(frames, tmp_path, monkeypatch):
    d, cal_path = frames
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InvalidInputError, match=r"pip install"):
        run_batch([str(d / "scene.png")], tmp_path / "o", BatchSettings(refocus_m=(0.5,), calibration=load_calibration(cal_path)),
                  executor="dask")
    assert not (tmp_path / "o" / "scene_refocus_0.5m.png").exists()



_CUT_OFF_WORKER = '''
import os, struct, sys, time
from pathlib import Path

from lfring.batch.executors import LocalPool


def cut_off(marker, then):
    """In the worker: begin a result on the pool's result queue (a header for 1 MiB, 16 bytes of
    it) and stop sending, as a worker lost while it sends a frame's outputs leaves the queue;
    then wait to be stopped, or die."""
    result_queue = sys._getframe(1).f_locals["result_queue"]
    os.write(result_queue._writer.fileno(), struct.pack("!i", 1 << 20) + bytes(16))
    Path(marker).touch()
    if then == "die":
        os._exit(1)
    time.sleep(120)


if __name__ == "__main__":
    marker, then = Path(sys.argv[1]), sys.argv[2]
    pool = LocalPool(1)
    fut = pool.submit(cut_off, str(marker), then)
    manager = pool._pool._executor_manager_thread  # the thread the interpreter joins at exit
    if then == "die":
        done, _ = pool.wait([fut])
    else:
        t0 = time.monotonic()
        while not marker.exists() and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        time.sleep(0.2)  # the pool's manager thread is now inside the message, waiting for the rest
        pool.terminate()
    print(type(fut.exception(timeout=10)).__name__, manager.is_alive())
'''


@pytest.mark.parametrize("then", ["terminate", "die"])
def test_a_pool_whose_worker_was_lost_inside_a_result_ends_and_lets_the_process_exit(tmp_path, then):
    """A worker lost while it sends a frame's outputs leaves its message cut short, and the pool's
    manager thread waiting for the rest. Stopped by the batch (Ctrl-C, SIGTERM), the pool must
    still end, or the process never exits (the interpreter joins that thread at exit); a worker
    that died there on its own (a crash, the OOM killer) must break the pool, as any lost worker
    does, or the batch waits for its frames for ever. Either way the pool's manager thread has
    ended when the stop returns."""
    import subprocess

    script = tmp_path / "cut_off_worker.py"
    script.write_text(_CUT_OFF_WORKER)
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path / "sending"), then], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # its worker too
        proc.communicate()
        pytest.fail(f"the process did not exit within 60 s ({then})")
    assert proc.returncode == 0, err
    assert out.split() == ["BrokenProcessPool", "False"]  # and the pool's thread ended with it


@pytest.mark.parametrize("return_when", ["FIRST_COMPLETED", "ALL_COMPLETED", "FIRST_EXCEPTION"])
def test_the_held_wait_returns_when_asked(return_when):
    """The pool's wait in slices returns as concurrent.futures.wait does: at the first finished
    future, when all are, or at the first exception (it returned at the first finished future
    whatever was asked)."""
    import concurrent.futures as cf
    import threading

    from lfring.batch.executors import WAIT_SLICE_S, held_wait

    futures = [cf.Future() for _ in range(3)]
    late = 3 * WAIT_SLICE_S
    threading.Timer(0.01, lambda: futures[0].set_result(0)).start()
    threading.Timer(late, lambda: futures[1].set_exception(ValueError("bad frame"))).start()
    threading.Timer(2 * late, lambda: futures[2].set_result(2)).start()
    done, not_done = held_wait(futures, getattr(cf, return_when))
    want = {"FIRST_COMPLETED": 1, "FIRST_EXCEPTION": 2, "ALL_COMPLETED": 3}[return_when]
    assert len(done) == want and len(not_done) == 3 - want
    cf.wait(futures)
