"""A batch run from start to end: :func:`run_batch` checks its arguments, finds the frames,
plans and checks their outputs, takes the output folder's lock, decides per frame what to
resume, runs the frames on the executor and writes what comes back, with a record and a
manifest line per frame; :class:`BatchReport` says how it went."""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import shutil
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from lfring.batch.discovery import WRONG_SIZE, BatchJob, frame_size, plan_jobs, scan_inputs
from lfring.batch.executors import (
    EXECUTORS,
    DaskExecutor,
    InProcess,
    LocalPool,
    dask_client,
    dask_wait,
    local_executor,
)
from lfring.batch.pipeline import FrameResult, process_frame
from lfring.batch.record import (
    DIGEST_KEY,
    MANIFEST,
    RECORD_SUFFIX,
    RECORD_VERSION,
    OutputWriter,
    append_manifest,
    as_recorded,
    decide_resume,
    file_identity,
    input_identity,
    is_batch_manifest,
    made_with,
    outdir_lock,
    read_record,
    same_input,
)
from lfring.batch.settings import BatchSettings
from lfring.core.signals import deliver_lost_stops, held_signals
from lfring.core.validate import check_choice, check_int
from lfring.errors import InvalidInputError, LfringError
from lfring.io.readers import RECORD_KEY
from lfring.io.writers import check_output_folder

__all__ = ["BatchReport", "run_batch"]

log = logging.getLogger("lfring.batch")


@dataclass
class BatchReport:
    """The outcome of :func:`run_batch`.

    ``done``, ``skipped`` and ``failed`` are input paths; ``errors`` maps each failed input to
    its one-line error; ``not_frames`` lists (path, reason) of files in folder inputs left out
    because they are not frames; ``left_out`` lists (path, reason) of frames read and left out
    because they hold no scene (flat fields); ``elapsed_s`` is the wall time; ``frames_per_s``
    counts processed (not skipped) frames.
    """

    outdir: str
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    elapsed_s: float = 0.0
    manifest: str = ""
    not_frames: list = field(default_factory=list)
    left_out: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when no frame failed (every frame done or skipped)."""
        return not self.failed

    @property
    def exit_code(self) -> int:
        """0 when every frame is done or skipped, 1 when some failed."""
        return 0 if self.ok else 1

    @property
    def frames_per_s(self) -> float:
        """Frames processed (not skipped) per second of wall time; 0 when none was processed."""
        return len(self.done) / self.elapsed_s if self.elapsed_s > 0 and self.done else 0.0

    def summary(self) -> str:
        """One line for the end of a run: counts of done, skipped and failed frames, the time,
        the rate, the output folder and the files left out as not frames.

        Returns
        -------
        str
        """
        n = len(self.done) + len(self.skipped) + len(self.failed) + len(self.left_out)
        rate = f", {self.frames_per_s:.2f} frames/s" if self.done else ""
        sized = sum(1 for _, why in self.not_frames if why.endswith(WRONG_SIZE))
        others = len(self.not_frames) - sized
        parts = []
        if sized:
            parts.append(f"{sized} frame{'s' * (sized > 1)} of a size no calibration fits")
        if others:
            parts.append(f"{others} files that are not frames" if others > 1 else "1 file that is not a frame")
        left = f"; {' and '.join(parts)} left out" if parts else ""
        flats = ""
        if self.left_out:
            flats = f"; {len(self.left_out)} left out ({', '.join(sorted({why.split(' (')[0] for _, why in self.left_out}))})"
        return (f"{n} frame{'s' * (n != 1)}: {len(self.done)} done, {len(self.skipped)} skipped (already done), "
                f"{len(self.failed)} failed in {self.elapsed_s:.1f} s{rate}{flats}; outputs in {self.outdir}{left}")


@dataclass
class _Run:
    """The state of one run shared by its steps."""

    out: Path
    settings: BatchSettings
    plan: dict
    report: BatchReport
    run_id: str
    writer: OutputWriter
    on_result: Callable[[dict], None] | None
    identity: dict = field(default_factory=dict)
    todo_kinds: dict = field(default_factory=dict)  # input -> kinds computed this run
    # input -> what the record keeps of earlier runs' outputs that are still valid: their outputs,
    # output_keys, output_identity and output_runs, and the settings of those runs by run id
    carried: dict = field(default_factory=dict)
    previous: dict = field(default_factory=dict)  # input -> its record as it stood before this run
    calibrations: dict = field(default_factory=dict)  # input -> the frame's calibration, when it can be told
    _keys: dict = field(default_factory=dict)  # id of a calibration -> output keys

    def planned(self, job: BatchJob) -> dict[str, str]:
        """Kind -> relative path of the outputs this run computes for ``job``."""
        kinds = self.todo_kinds.get(job.input, tuple(self.plan[job.input]))
        return {k: self.plan[job.input][k] for k in kinds}

    def keys(self, job: BatchJob) -> dict[str, str]:
        """:meth:`BatchSettings.output_keys` for ``job``'s calibration (computed once per calibration)."""
        cal = self.calibrations.get(job.input)
        if id(cal) not in self._keys:
            self._keys[id(cal)] = self.settings.output_keys(cal)
        return self._keys[id(cal)]

    def entry(self, job: BatchJob, status: str, **kw) -> dict:
        # A line lists the files this run wrote for the frame, and no other: those of a frame
        # that failed or was left out go apart, as the files it was to write.
        planned = list(self.planned(job).values())
        wrote = planned if status == "done" else []
        record = job.stem + RECORD_SUFFIX
        if status == "left_out" and not (self.out / record).exists():
            record = None  # a frame left out gets no record: the line names none
        e = {"run": self.run_id, "input": job.input, "status": status, "outputs": wrote,
             "record": record, "settings_key": self.settings.key(), **kw}
        if status in ("failed", "left_out") and planned:
            e["planned_outputs"] = planned
        append_manifest(self.out / MANIFEST, e)
        if self.on_result is not None:
            self.on_result(e)
        return e

    def record(self, job: BatchJob, status: str, **extra) -> None:
        # 'outputs' lists the frame's files that exist (earlier runs' still valid, and this
        # run's once written); the files a pending or failed run was to write are listed apart,
        # so that a rerun knows them as its own.
        # 'settings' are this run's; an output an earlier run made names that run in
        # 'output_runs', and that run's settings are in 'earlier_settings' (outputs of records
        # written before that are left out of both: which run made them is not known).
        outputs, keys, identities, runs, earlier = self.carried.get(job.input, ({}, {}, {}, {}, {}))
        planned = self.planned(job)
        planned_keys = self.keys(job)
        new = {k: planned_keys[k] for k in planned}
        done = status == "done"
        if done:  # this run's files as it wrote them; the earlier ones as their records found them
            identities = {**identities, **self._identities(planned)}
        self.writer.write_json(job.stem + RECORD_SUFFIX, {
            RECORD_KEY: RECORD_VERSION, "status": status, "run": self.run_id, "input": job.input,
            "input_identity": self._input_identity(job.input), "settings_key": self.settings.key(),
            "settings": self.settings.describe(), "outputs": {**outputs, **planned} if done else dict(outputs),
            "planned_outputs": {} if done else planned,
            "output_keys": {**keys, **new} if done else keys,
            "output_runs": {**runs, **dict.fromkeys(planned, self.run_id)} if done else dict(runs),
            "output_identity": identities,
            "earlier_settings": earlier,
            "pending_keys": {} if done else new, "lfring_version": _version(), **extra})

    def _input_identity(self, path: str) -> dict:
        """The input's identity as records keep it, its digests too (read once a run)."""
        ident = self.identity[path]
        if DIGEST_KEY not in ident:
            with contextlib.suppress(OSError):
                now = input_identity(path, digest=True)
                if same_input(ident, now):  # as planned: else the planned identity stays, and the frame fails
                    ident = self.identity[path] = now
        return ident

    def _identities(self, outputs: dict) -> dict:
        """{relative path: file identity} of the outputs listed that exist, with their digests: a
        rerun then tells a file written since by hand from the one this tool wrote (and a copy
        that did not keep the times from either)."""
        out = {}
        for rel in outputs.values():
            with contextlib.suppress(OSError):
                out[rel] = file_identity(str(self.out / rel), digest=True)
        return out

    def fail(self, job: BatchJob, error: str, record_it: bool = False, **kw) -> None:
        self.report.failed.append(job.input)
        self.report.errors[job.input] = error
        log.error("%s", error if error.startswith(job.input) else f"{job.input}: {error}")
        if record_it:  # our pending record becomes a failed one (a rerun tries the frame again)
            with contextlib.suppress(OSError):
                self.record(job, "failed", error=error)
        self.entry(job, "failed", error=error, **kw)


def _check_run_args(executor, scheduler, workers, settings, out: Path) -> int:
    check_choice(executor, "executor", EXECUTORS)
    if scheduler and executor != "dask":
        raise InvalidInputError("a scheduler address goes with executor='dask' (--executor dask)")
    if workers is None:
        workers = os.cpu_count() or 1
    workers = check_int(workers, "workers", minimum=1)
    if not isinstance(settings, BatchSettings):
        raise InvalidInputError(f"settings must be a BatchSettings, got {type(settings).__name__}")
    if out.exists() and not out.is_dir():
        raise InvalidInputError(f"{out} exists and is not a folder")
    return workers


def _frame_sizes(settings: BatchSettings):
    """Sizes (width, height) a frame may have: the calibration's, or those of the built-in ones."""
    if settings.calibration is not None:
        return {tuple(settings.calibration.raw_size)}
    from lfring.calibration.defaults import builtin_calibrations

    return {tuple(s) for s in builtin_calibrations().values()}


def _frame_calibration(settings: BatchSettings, path: str, builtin: dict):
    """The calibration a frame is processed with, when it can be told from its header: the
    settings', or the built-in one for its size (``builtin`` caches them by size); else None."""
    if settings.calibration is not None:
        return settings.calibration
    size = frame_size(path)
    if not size or size == (0, 0):
        return None
    if size not in builtin:
        from lfring.calibration.defaults import default_calibration

        try:
            builtin[size] = default_calibration(size)[0]
        except LfringError:  # no built-in calibration fits: the frame fails with that error
            builtin[size] = None
    return builtin[size]


def _changed_since(out: Path, rec: dict, outs: dict, existing: set) -> str | None:
    """The first output asked for that the frame's record ``rec`` says a run made, but that is
    no longer as the record found it (written since by another command or by hand), or None
    (records of versions that kept no ``output_identity`` cannot tell)."""
    made = rec.get("output_identity") or {}
    listed = rec.get("outputs") or {}
    for kind, rel in outs.items():
        if rel in existing and listed.get(kind) == rel and rel in made and not as_recorded(made, rel, out / rel):
            return rel
    return None


def _decide_jobs(run: _Run, jobs: Sequence[BatchJob], overwrite: bool) -> list[BatchJob]:
    """Apply :func:`decide_resume` to every frame: skipped and refused frames are reported, the
    rest returned with the outputs each must compute in ``run.todo_kinds``."""
    alias_keys = run.settings.output_keys(resolved=False)
    builtin: dict = {}
    todo: list[BatchJob] = []
    for job in jobs:
        outs = run.plan[job.input]
        rec_path = run.out / (job.stem + RECORD_SUFFIX)
        rec = read_record(rec_path)
        try:
            ident = run.identity[job.input] = input_identity(job.input)
        except OSError as exc:
            run.fail(job, f"cannot read the input: {exc.strerror or exc}")
            continue
        cal = run.calibrations[job.input] = _frame_calibration(run.settings, job.input, builtin)
        existing = {rel for rel in outs.values() if (run.out / rel).exists()}
        changed = None if overwrite or rec is None else _changed_since(run.out, rec, outs, existing)
        if changed is not None:
            run.fail(job, f"{changed} exists and was written since lfring batch made it (by another command or by hand); "
                          "pass --overwrite to replace it, or -o to write elsewhere")
            continue
        d = decide_resume(outs, run.keys(job), rec, ident, existing, record_exists=rec_path.exists(), overwrite=overwrite,
                          settings_key=run.settings.legacy_key() or "", alias_keys=alias_keys,
                          explain=lambda kind, record, cal=cal: run.settings.differences(kind, record, cal),
                          input_path=job.input)
        if d.action == "refuse":
            run.fail(job, d.reason)
            continue
        if d.action == "skip":
            run.report.skipped.append(job.input)
            run.todo_kinds[job.input] = ()
            run.entry(job, "skipped")
            continue
        run.todo_kinds[job.input] = d.kinds
        if rec is not None:
            run.previous[job.input] = rec
        if rec is not None and same_input(rec.get("input_identity"), ident, job.input):
            # Earlier runs' outputs that are still valid and still there stay in the record.
            made = rec.get("outputs") or {}
            keep = {k: v for k, v in (rec.get("output_keys") or {}).items()
                    if k not in d.kinds and k in made and (run.out / made[k]).exists()}
            kept = {k: made[k] for k in keep}
            identities = {rel: v for rel, v in (rec.get("output_identity") or {}).items() if rel in kept.values()}
            runs = {k: r for k, r in (rec.get("output_runs") or {}).items() if k in keep and isinstance(r, str)}
            known = {r: made_with(rec, r) for r in set(runs.values())}
            runs = {k: r for k, r in runs.items() if known[r] is not None}
            run.carried[job.input] = (kept, keep, identities, runs, {r: known[r] for r in set(runs.values())})
        todo.append(job)
    return todo


def _check_manifest(out: Path, writer: OutputWriter, overwrite: bool) -> None:
    """Refuse to append to a ``manifest.jsonl`` that lfring batch did not write, unless told to
    replace it (``overwrite``): it may be somebody's file."""
    path = out / MANIFEST
    if not (path.exists() or path.is_symlink()) or is_batch_manifest(path):
        return
    if not overwrite:
        raise InvalidInputError(
            f"{path} exists and is not a manifest of lfring batch (its lines are not batch entries), so the batch "
            "neither appends to it nor replaces it: move it away, choose another output folder, or pass "
            "overwrite=True to replace it (and redo every frame)")
    log.warning("%s was not a manifest of lfring batch; replaced (overwrite)", path)
    writer.write(MANIFEST, b"")


def _progress(todo, progress):
    if not todo:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return None
    return tqdm(total=len(todo), unit="frame", desc="lfring batch", disable=(None if progress is None else not progress),
                dynamic_ncols=True, smoothing=0.1)


def _finish(run: _Run, job: BatchJob, res: FrameResult) -> None:
    """Write a worker's files for one frame, then its record and manifest line."""
    if res.left_out:
        # Not a scene: nothing written, so the record goes back to what it was before this run
        # (an earlier run's outputs stay its own), or away if there was none (a rerun looks again).
        rec_path = run.out / (job.stem + RECORD_SUFFIX)
        if (read_record(rec_path) or {}).get("run") == run.run_id:
            before = run.previous.get(job.input)
            with contextlib.suppress(OSError):
                if before is None:
                    rec_path.unlink()
                else:
                    run.writer.write_json(job.stem + RECORD_SUFFIX, before)
        run.report.left_out.append((job.input, res.left_out))
        log.info("%s: left out: %s", job.input, res.left_out)
        run.entry(job, "left_out", reason=res.left_out, timings_s=res.timings_s, worker=res.worker)
        return
    if not res.ok:
        run.fail(job, res.error, record_it=True, timings_s=res.timings_s, worker=res.worker)
        return
    try:
        unchanged = same_input(run.identity[job.input], input_identity(job.input), job.input)
    except OSError:
        unchanged = False
    if not unchanged:  # the outputs may be of a file still being written, or of the one before
        run.fail(job, "the frame (or its sidecar) changed or went after the run planned it: its outputs are not "
                      "written; run again once it is complete (with overwrite=True where earlier outputs of it exist)",
                 record_it=True, timings_s=res.timings_s, worker=res.worker)
        return
    t_w = time.perf_counter()
    deliver_lost_stops()  # a Ctrl-C that came where it could not stop the batch: this frame stays pending
    try:
        with held_signals():  # a frame's files and its record, all or none of them new
            for kind in run.todo_kinds[job.input]:
                run.writer.write(run.plan[job.input][kind], res.files[kind])
            run.record(job, "done", info=res.info, timings_s=res.timings_s)
    except OSError as exc:
        run.fail(job, f"cannot write its outputs: {exc.strerror or exc}", record_it=True)
        return
    res.timings_s["write"] = time.perf_counter() - t_w
    run.report.done.append(job.input)
    run.entry(job, "done", timings_s=res.timings_s, worker=res.worker, info=res.info)
    named = (f"{job.input}: ", f"{os.path.abspath(job.input)}: ")  # a cluster's workers read the absolute path
    for w in res.info.get("warnings", []):  # a reader's notes name the frame already
        log.warning("%s", w if w.startswith(named) else f"{job.input}: {w}")


def _execute(run: _Run, todo: list[BatchJob], *, workers: int, executor: str, scheduler, progress) -> None:
    """Process the frames on the executor, a window of them at a time. A lost local worker breaks
    its pool and every frame the pool held: those frames are suspects, run again one at a time
    in a pool of one worker, where a loss is the frame's own (it fails); then the others go on."""
    bar = _progress(todo, progress)
    cluster = client = None
    pool = None
    try:
        if todo:
            if executor == "dask":
                client, cluster = dask_client(workers, scheduler)
                pool, waiter = DaskExecutor(client), dask_wait
            else:
                pool, waiter = local_executor(min(workers, len(todo)))
        window = max(2, 2 * workers)
        pending: dict = {}
        queue = list(todo)
        suspects: list[BatchJob] = []  # frames a broken pool held, run one at a time
        solo = False  # the pool runs one suspect at a time

        def submit(job: BatchJob) -> None:
            run.record(job, "pending")
            # A cluster's workers resolve a relative path in their own working folder.
            path = os.path.abspath(job.input) if executor == "dask" else job.input
            pending[pool.submit(process_frame, path, run.settings, run.planned(job))] = job

        def renew() -> None:
            """A fresh pool of worker processes (never this process: a frame may kill it): one
            worker while there are suspects, else as many as the queue needs."""
            nonlocal pool, waiter, solo
            pool.shutdown(wait=False, cancel_futures=True)
            solo = bool(suspects)
            if suspects or queue:
                pool = LocalPool(1 if solo else min(workers, len(queue)))
                waiter = pool.wait

        while queue or pending or suspects:
            source, room = (suspects, 1) if solo or suspects else (queue, window)
            if source is suspects and not solo:
                renew()
            while source and len(pending) < room:
                job = source.pop(0)
                try:
                    submit(job)
                except OSError as exc:
                    run.fail(job, f"cannot write its record: {exc}")
                except BrokenProcessPool as exc:  # a worker died since the last results were taken
                    if solo:  # a pool of one, fresh for this frame: its worker is lost to it
                        run.fail(job, f"the worker processing it was lost: {type(exc).__name__}: {exc}", record_it=True)
                    else:
                        suspects[:0] = [job, *pending.values()]
                        pending.clear()
                    renew()
                    break
            if not pending:
                if solo and not suspects:
                    renew()  # the suspects are done: the others go on
                continue
            done_set, _ = waiter(list(pending), return_when=FIRST_COMPLETED)
            for fut in done_set:
                job = pending.pop(fut)
                try:
                    with held_signals():  # taking the result takes the future's lock
                        res: FrameResult = fut.result()
                except Exception as exc:  # noqa: BLE001 - a worker died (crash, killed)
                    if executor == "local" and not isinstance(pool, InProcess) and not solo:
                        held = [job, *pending.values()]
                        log.warning("a worker was lost (%s) with %d frame(s) in its pool; running them again one at a "
                                    "time", type(exc).__name__, len(held))
                        suspects[:0] = held
                        pending.clear()
                        renew()
                        break
                    run.fail(job, f"the worker processing it was lost: {type(exc).__name__}: {exc}", record_it=True)
                    if bar is not None:
                        bar.update(1)
                    if solo:  # its own loss: the pool is broken, the next suspect gets a fresh one
                        renew()
                        break
                    continue
                _finish(run, job, res)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(failed=len(run.report.failed), refresh=False)
    except BaseException:
        # Interrupted (Ctrl-C, SIGTERM) or failed: the workers stop now, their frames stay pending
        # for a rerun; waiting for them could take as long as a frame.
        if pool is not None:
            pool.terminate()
            pool = None
        raise
    finally:
        if bar is not None:
            bar.close()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


def run_batch(
    inputs: Sequence[str],
    outdir: str | Path,
    settings: BatchSettings,
    *,
    workers: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    overwrite: bool = False,
    exclude: Sequence[str] = (),
    progress: bool | None = False,
    on_result: Callable[[dict], None] | None = None,
) -> BatchReport:
    """Process every frame of ``inputs`` (files, folders, glob patterns) into ``outdir``.

    Parameters
    ----------
    inputs : sequence of str
    outdir : str or Path
        Created if missing. Outputs keep the folder structure of folder inputs.
    settings : BatchSettings
    workers : int, optional
        Worker processes (default: the number of cores); 1 runs the frames in this process.
    executor : {'local', 'dask'}
        'dask' runs on the cluster at ``scheduler`` (an address such as 'tcp://host:8786'),
        or on a local Dask cluster of ``workers`` processes when none is given. The workers must
        see the inputs at the same paths; outputs come back to this process, which writes them.
    overwrite : bool
        Redo frames already done and replace files this run did not make (a ``manifest.jsonl``
        in ``outdir`` that is not a batch's included).
    exclude : sequence of str
        Glob patterns of files to leave out of folder inputs.
    progress : bool or None
        A progress bar on stderr (None: only when stderr is a terminal).
    on_result : callable, optional
        Called with each manifest entry as it is written.

    Returns
    -------
    BatchReport
        ``exit_code`` is 0 when all frames are done or skipped, 1 when some failed.

    Raises
    ------
    InvalidInputError
        Bad arguments, no inputs, outputs that would collide, a ``manifest.jsonl`` in ``outdir``
        that a batch did not write (unless ``overwrite``): nothing is processed.

    Notes
    -----
    The worker processes are started with ``spawn`` (forking a process whose OpenCV threads run
    can deadlock), so a script that calls this with ``workers > 1`` must do so under
    ``if __name__ == "__main__":``, as with any spawning process pool.

    Examples
    --------
    The bundled scene (data/synthetic, paths relative to the repository root) refocused at
    0.5 m into a temporary folder, then the same run again, which finds it done:

    >>> import os, tempfile
    >>> import lfring.batch
    >>> settings = lfring.batch.BatchSettings(refocus_m=(0.5,))
    >>> with tempfile.TemporaryDirectory() as out:
    ...     first = lfring.batch.run_batch(["data/synthetic/scene.png"], out, settings, workers=1, progress=False)
    ...     again = lfring.batch.run_batch(["data/synthetic/scene.png"], out, settings, workers=1, progress=False)
    ...     files = sorted(os.listdir(out))
    >>> first.exit_code, len(first.done), len(again.done), len(again.skipped)
    (0, 1, 0, 1)
    >>> files
    ['manifest.jsonl', 'scene.lfring.json', 'scene_refocus_0.5m.png']
    """
    out = check_output_folder(outdir)
    workers = _check_run_args(executor, scheduler, workers, settings, out)
    jobs, not_frames = scan_inputs(inputs, outdir=out, exclude=exclude, frame_sizes=_frame_sizes(settings))
    plan = plan_jobs(jobs, settings, out)
    out.mkdir(parents=True, exist_ok=True)
    report = BatchReport(str(out), manifest=str(out / MANIFEST), not_frames=not_frames)
    t0 = time.perf_counter()
    # Unique among runs: two runs of one process may start within a second.
    run_id = time.strftime("%Y%m%dT%H%M%S") + f"-{os.getpid()}-{secrets.token_hex(3)}"
    with outdir_lock(out):
        writer = OutputWriter(out)
        # Temporary files left by a killed run are never outputs; clear them.
        if writer.tmp.exists():
            shutil.rmtree(writer.tmp, ignore_errors=True)
        run = _Run(out, settings, plan, report, run_id, writer, on_result)
        try:
            _check_manifest(out, writer, overwrite)
            todo = _decide_jobs(run, jobs, overwrite)
            _execute(run, todo, workers=workers, executor=executor, scheduler=scheduler, progress=progress)
        finally:
            with held_signals():  # a stop that comes now waits for the folder to be gone
                shutil.rmtree(writer.tmp, ignore_errors=True)
    report.elapsed_s = time.perf_counter() - t0
    return report


def _version() -> str:
    from lfring import __version__

    return __version__
