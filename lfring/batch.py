"""Batch processing of folders of raw frames: refocus, depth and all-in-focus for every frame.

The pipeline of one frame (:func:`process_frame`) runs in worker processes, on this machine
(``executor='local'``) or on a Dask cluster (``executor='dask'``); it returns the encoded output
files as bytes. This process alone writes into the output folder, so every write is atomic,
nothing is written twice and no output escapes the folder, whatever the workers do.

Safety rules, for every run:

- inputs are only read;
- an output is written through a temporary file in ``OUTDIR/.lfring-tmp`` and renamed into
  place, so a killed run leaves complete files or none;
- each frame gets a record ``<name>.lfring.json`` beside its outputs, written ``pending``
  before its outputs and ``done`` after them; a rerun skips frames whose record is done with the
  same settings and the same input, and never replaces files it did not make unless asked to
  (``overwrite=True``);
- a frame that fails is reported by name and the others go on;
- ``OUTDIR/manifest.jsonl`` gets one JSON line per frame and run (input, outputs, timings,
  status, error).
"""

from __future__ import annotations

import contextlib
import fnmatch
import glob
import hashlib
import json
import logging
import os
import shutil
import socket
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from lfring.depth import SGM_MIN_PLANES
from lfring.errors import InvalidInputError, LfringError, LfringWarning
from lfring.io.atomic import atomic_write_bytes
from lfring.io.writers import json_default
from lfring.core.warping import DEFAULT_INTERPOLATION

__all__ = [
    "EXECUTORS",
    "BatchJob",
    "BatchReport",
    "BatchSettings",
    "FrameResult",
    "ResumeDecision",
    "decide_resume",
    "find_inputs",
    "frame_size",
    "scan_inputs",
    "plan_jobs",
    "process_frame",
    "read_manifest",
    "run_batch",
]

log = logging.getLogger("lfring.batch")

EXECUTORS = ("local", "dask")
TMP_DIR = ".lfring-tmp"
LOCK_FILE = ".lfring-batch.lock"
MANIFEST = "manifest.jsonl"
RECORD_SUFFIX = ".lfring.json"
RECORD_VERSION = 1

_DASK_HINT = 'install it with: python3 -m pip install -c constraints.txt ".[dask]"  (or: pip install "dask[distributed]")'


def _frame_suffixes() -> frozenset[str]:
    from lfring.io.raw import RAW_SUFFIXES

    return frozenset(RAW_SUFFIXES) | {".png", ".tif", ".tiff"}


# -- settings ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BatchSettings:
    """What to make of every frame.

    Attributes
    ----------
    refocus_m : tuple of float
        Depths in metres to refocus at (one image each).
    depth : bool
        Also compute a depth map over ``zmin_m``..``zmax_m`` (metres).
    all_in_focus : bool
        Also write an all-in-focus image (from the depth map when there is one, else over the
        refocus depths when there are two or more, else over the calibrated range).
    calibration : RingCalibration, optional
        None: the built-in calibration for each frame's size.
    calibration_name : str
    reference : 'center' or int
    interpolation : {'cubic', 'linear'}
    bit_depth : {8, 16}
    encoding : {'srgb', 'linear'}
    planes : int, optional
        Number of depth hypotheses (default: at most 1 px of view motion apart).
    depth_method : {'sgm', 'local'}
        ``method`` of :func:`lfring.estimate_depth` for the depth maps, with its default cost (the
        cost is part of the depth outputs' keys, so maps made with an earlier default are not
        taken for this run's).
    min_confidence : float
        Depth preview: pixels below it are black.
    viewer : bool
        Also write an interactive HTML viewer (:mod:`lfring.viewer`), its depth range
        ``zmin_m``..``zmax_m`` or the calibrated range.
    pattern, black_level, white_level : optional
        Bayer pattern and levels in counts for frames that lack them (they win over sidecars;
        see :func:`lfring.io.levels.load_frame`).
    check_frames : bool
        Refuse frames that do not look like ring frames for the calibration
        (:func:`lfring.check.check_frame`).
    """

    refocus_m: tuple[float, ...] = ()
    depth: bool = False
    zmin_m: float | None = None
    zmax_m: float | None = None
    all_in_focus: bool = False
    calibration: object = None
    calibration_name: str = "built-in"
    reference: object = "center"
    interpolation: str = DEFAULT_INTERPOLATION
    bit_depth: int = 8
    encoding: str = "srgb"
    planes: int | None = None
    depth_method: str = "sgm"
    min_confidence: float = 0.5
    viewer: bool = False
    pattern: str | None = None
    black_level: object = None
    white_level: float | None = None
    check_frames: bool = True

    def __post_init__(self):
        zs = tuple(float(z) for z in self.refocus_m)
        object.__setattr__(self, "refocus_m", zs)
        for z in zs:
            if not (np.isfinite(z) and z > 0):
                raise InvalidInputError(f"refocus depths must be positive, finite metres, got {z!r}")
        if len(set(zs)) != len(zs):
            raise InvalidInputError(f"refocus depths repeat: {list(zs)}")
        if not (zs or self.depth or self.all_in_focus or self.viewer):
            raise InvalidInputError("nothing to do: ask for refocus depths, a depth map, an all-in-focus image or a viewer")
        if self.depth:
            if self.zmin_m is None or self.zmax_m is None:
                raise InvalidInputError("a depth map needs zmin_m and zmax_m (--zmin, --zmax)")
            for name in ("zmin_m", "zmax_m"):
                v = getattr(self, name)
                if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                    raise InvalidInputError(f"{name} must be a positive, finite number of metres, got {v!r}")
            if not self.zmin_m < self.zmax_m:
                raise InvalidInputError(f"zmin_m ({self.zmin_m}) must be smaller than zmax_m ({self.zmax_m})")
        if self.interpolation not in ("cubic", "linear"):
            raise InvalidInputError(f"interpolation must be 'cubic' or 'linear', got {self.interpolation!r}")
        if self.bit_depth not in (8, 16):
            raise InvalidInputError(f"bit_depth must be 8 or 16, got {self.bit_depth!r}")
        if self.encoding not in ("srgb", "linear"):
            raise InvalidInputError(f"encoding must be 'srgb' or 'linear', got {self.encoding!r}")
        if self.depth_method not in ("sgm", "local"):
            raise InvalidInputError(f"depth_method must be 'sgm' or 'local', got {self.depth_method!r}")
        # The viewer's depth map, when the batch makes none, is the semi-global default.
        least = SGM_MIN_PLANES if (self.depth and self.depth_method == "sgm") or self.viewer else 2
        if self.planes is not None and (isinstance(self.planes, bool) or not isinstance(self.planes, int) or self.planes < least):
            raise InvalidInputError(f"planes must be an integer >= {least}"
                                    f"{' for the semi-global depth' if least > 2 else ''}, got {self.planes!r}")
        if not (0.0 <= self.min_confidence <= 1.0):
            raise InvalidInputError(f"min_confidence must lie in [0, 1], got {self.min_confidence!r}")

    def outputs(self, stem: str) -> dict[str, str]:
        """Kind -> output path relative to OUTDIR, for a frame whose relative stem is ``stem``."""
        out = {f"refocus_{z:g}m": f"{stem}_refocus_{z:g}m.png" for z in self.refocus_m}
        if self.all_in_focus:
            out["all_in_focus"] = f"{stem}_all_in_focus.png"
        if self.depth:
            out["depth"] = f"{stem}_depth.tiff"
            out["confidence"] = f"{stem}_confidence.tiff"
            out["depth_preview"] = f"{stem}_depth_preview.png"
        if self.viewer:
            out["viewer"] = f"{stem}_viewer.html"
        return out

    def output_keys(self) -> dict[str, str]:
        """Kind -> a short hash of every setting that changes that output: a rerun that adds an
        output (another refocus depth, a depth map) recomputes only the outputs whose key is new."""
        d = self.describe()
        common = {k: d[k] for k in ("calibration_name", "calibration_sha256", "reference", "bit_depth", "encoding", "pattern",
                                    "black_level", "white_level")}
        depth_part = {k: d[k] for k in ("zmin_m", "zmax_m", "planes", "min_confidence", "depth_method")}
        if self.depth_method == "sgm":
            # The method's default cost: depth maps made before it changed ('lcn' until 'lcn-halves')
            # are not this run's; a resumed folder refuses them unless told to overwrite.
            from lfring.depth.engines import ENGINES

            depth_part["depth_cost"] = ENGINES["sgm"].default_cost

        def h(obj) -> str:
            return hashlib.sha256(json.dumps(obj, sort_keys=True, default=json_default).encode()).hexdigest()[:16]

        keys = {f"refocus_{z:g}m": h({**common, "refocus_m": z, "interpolation": self.interpolation}) for z in self.refocus_m}
        if self.all_in_focus:
            source = ({"depth": depth_part} if self.depth
                      else {"depths_m": list(self.refocus_m)} if len(self.refocus_m) > 1 else {"depths_m": "calibrated range"})
            keys["all_in_focus"] = h({**common, "all_in_focus": source})
        if self.depth:
            for kind in ("depth", "confidence", "depth_preview"):
                keys[kind] = h({**common, **depth_part, "kind": kind})
        if self.viewer:
            keys["viewer"] = h({**common, **depth_part, "kind": "viewer", "depth": self.depth})
        return keys

    def describe(self) -> dict:
        """The settings as JSON-ready values (the calibration by name and content hash)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "calibration"}
        d["refocus_m"] = list(self.refocus_m)
        if not self.viewer:  # keeps the keys of folders made before the viewer existed
            del d["viewer"]
        if isinstance(self.black_level, tuple):
            d["black_level"] = list(self.black_level)
        d["calibration_sha256"] = None
        if self.calibration is not None:
            blob = json.dumps(self.calibration.to_dict(), sort_keys=True, default=json_default).encode()
            d["calibration_sha256"] = hashlib.sha256(blob).hexdigest()
        return d

    def legacy_key(self) -> str | None:
        """:meth:`key` as lfring computed it before raw levels and the frame check were settings
        (records of that time carry it), or None when those settings are not at their defaults."""
        new = ("pattern", "black_level", "white_level", "check_frames", "depth_method")
        if any(getattr(self, n) is not None for n in new[:3]) or not self.check_frames:
            return None
        if self.depth and self.depth_method != "local":  # that version's depth maps came from the local sweep
            return None
        d = {k: v for k, v in self.describe().items() if k not in new}
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=json_default).encode()).hexdigest()[:16]

    def key(self) -> str:
        """A short hash of everything that changes the outputs (computed once per instance)."""
        k = self.__dict__.get("_key")
        if k is None:
            blob = json.dumps(self.describe(), sort_keys=True, default=json_default).encode()
            k = hashlib.sha256(blob).hexdigest()[:16]
            object.__setattr__(self, "_key", k)  # frozen: a memo, not a field
        return k


# -- inputs --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BatchJob:
    """One frame: its path, and the stem of its outputs relative to OUTDIR (folders kept)."""

    input: str
    stem: str


def _is_under(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


def find_inputs(inputs: Sequence[str], *, outdir: str | Path | None = None, exclude: Sequence[str] = ()) -> list[BatchJob]:
    """Expand files, folders (recursively) and glob patterns into jobs; see :func:`scan_inputs`
    (this keeps every file with a frame suffix)."""
    return scan_inputs(inputs, outdir=outdir, exclude=exclude)[0]


TRUTH_SUFFIX = "_truth"
"""Folders whose name ends so hold a frame's ground truth (the synthetic twin writes them): never
frames."""


def frame_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) of a PNG or TIFF read from its header (no pixels), None when it cannot
    be told cheaply (camera RAW, unreadable files: the frame's own error says why later) or the
    file holds float samples (a map, not raw counts: size (0, 0))."""
    p = Path(path)
    suffix = p.suffix.lower()
    try:
        if suffix == ".png":
            with open(p, "rb") as f:
                head = f.read(24)
            if len(head) == 24 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
            return None
        if suffix in (".tif", ".tiff"):
            import tifffile

            with tifffile.TiffFile(p) as tf:
                page = tf.pages[0]
                if np.dtype(page.dtype).kind == "f":
                    return (0, 0)
                return int(page.imagewidth), int(page.imagelength)
    except Exception:  # noqa: BLE001 - any unreadable header: not decided here
        return None
    return None


def scan_inputs(inputs: Sequence[str], *, outdir: str | Path | None = None, exclude: Sequence[str] = (),
                frame_sizes=None) -> tuple[list[BatchJob], list[tuple[str, str]]]:
    """Expand files, folders (recursively) and glob patterns into jobs, and list the files of
    folders that are not frames.

    Folder walks leave out, besides hidden files and suffixes that are not frames, ground-truth
    folders (``*_truth/``) and, when ``frame_sizes`` (a collection of (width, height)) is given,
    PNG/TIFF files whose header says another size or float samples. Files named explicitly or
    matched by a glob are always taken.

    Returns
    -------
    jobs : list of BatchJob
    skipped : list of (path, reason)
    """
    skipped: list[tuple[str, str]] = []
    sizes = None if frame_sizes is None else {tuple(s) for s in frame_sizes}
    jobs = _expand_inputs(inputs, outdir=outdir, exclude=exclude, skipped=skipped, sizes=sizes)
    return jobs, skipped


def _expand_inputs(inputs, *, outdir, exclude, skipped, sizes) -> list[BatchJob]:
    """Expand files, folders (recursively) and glob patterns into jobs.

    Folders yield the files with a raw-frame suffix (camera RAW, PNG, TIFF), hidden files and
    folders left out; a file named explicitly is taken whatever its suffix. Files inside
    ``outdir`` are never inputs (a rerun must not process its own outputs). ``exclude`` holds
    glob patterns matched against each file's name and its path relative to its folder argument.
    Output stems keep the folder structure below each folder argument; a file or a glob match
    gives its bare name.

    Raises
    ------
    InvalidInputError
        An argument matches nothing, or two inputs would write the same outputs.
    """
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    if not inputs:
        raise InvalidInputError("no inputs given: name files, folders or glob patterns")
    out_res = Path(outdir).resolve() if outdir is not None else None
    suffixes = _frame_suffixes()
    found: list[tuple[Path, str]] = []

    def excluded(rel: str) -> bool:
        return any(fnmatch.fnmatch(rel, pat) or fnmatch.fnmatch(Path(rel).name, pat) for pat in exclude)

    def keep(p: Path) -> bool:
        return out_res is None or not _is_under(p.resolve(), out_res)

    for arg in inputs:
        arg = str(arg)
        p = Path(arg)
        if p.is_dir():
            n0 = len(found)
            for root, dirs, files in os.walk(p):
                for d in sorted(dirs):
                    if d.endswith(TRUTH_SUFFIX) and not d.startswith("."):
                        skipped.append((str(Path(root, d)) + os.sep, "a ground-truth folder"))
                dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not d.endswith(TRUTH_SUFFIX) and keep(Path(root, d)))
                for name in sorted(files):
                    f = Path(root, name)
                    rel = f.relative_to(p).as_posix()
                    if name.startswith(".") or excluded(rel) or not keep(f):
                        continue
                    if f.suffix.lower() not in suffixes:
                        if f.suffix.lower() == ".json":
                            skipped.append((str(f), "a sidecar or record (JSON)"))
                        continue
                    if sizes is not None:
                        size = frame_size(f)
                        if size == (0, 0):
                            skipped.append((str(f), "float samples (a map, not raw counts)"))
                            continue
                        if size is not None and size not in sizes:
                            skipped.append((str(f), f"{size[0]} x {size[1]} px, a size no calibration fits"))
                            continue
                    found.append((f, rel))
            if len(found) == n0:
                log.warning("%s: no frames found (suffixes %s)", arg, ", ".join(sorted(suffixes)))
        elif p.is_file():
            if keep(p) and not excluded(p.name):
                found.append((p, p.name))
        elif glob.has_magic(arg):
            matches = sorted(glob.glob(arg, recursive=True))
            files = [Path(m) for m in matches if Path(m).is_file()]
            files = [f for f in files if keep(f) and not excluded(f.name) and not f.name.endswith(".json")]
            if not files:
                raise InvalidInputError(f"{arg}: the pattern matches no files")
            found.extend((f, f.name) for f in files)
        else:
            raise InvalidInputError(f"{arg}: no such file or folder")
    # The same file named twice (a folder and a glob, say) is one job.
    seen: dict[Path, BatchJob] = {}
    for f, rel in found:
        res = f.resolve()
        if res not in seen:
            stem = rel[: -len(Path(rel).suffix)] if Path(rel).suffix else rel
            seen[res] = BatchJob(str(f), stem)
    jobs = list(seen.values())
    if not jobs:
        raise InvalidInputError(f"no frames found in {', '.join(map(str, inputs))}")
    return jobs


def plan_jobs(jobs: Sequence[BatchJob], settings: BatchSettings, outdir: str | Path) -> dict[str, dict[str, str]]:
    """Input -> {kind: relative output path}; refuses names that collide or leave ``outdir``."""
    out_res = Path(outdir).resolve()
    owner: dict[str, str] = {}
    plan = {}
    for job in jobs:
        outs = settings.outputs(job.stem)
        for rel in [*outs.values(), job.stem + RECORD_SUFFIX]:
            target = (out_res / rel).resolve()
            if not _is_under(target, out_res) or target == out_res:
                raise InvalidInputError(f"{job.input}: output {rel!r} would leave the output folder {outdir}")
            key = os.path.normcase(str(target))
            if key in owner and owner[key] != job.input:
                raise InvalidInputError(
                    f"{owner[key]} and {job.input} would both write {rel}: rename one, or run them into different folders")
            owner[key] = job.input
        plan[job.input] = outs
    return plan


# -- one frame (runs in a worker) ----------------------------------------------------------------
@dataclass
class FrameResult:
    """What a worker sends back for one frame: encoded files or an error, and timings."""

    input: str
    ok: bool
    files: dict[str, bytes] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    error: str | None = None
    worker: str = ""


_WORKER_CACHE: dict = {}


def _worker_calibration(settings: BatchSettings, size_wh):
    if settings.calibration is not None:
        return settings.calibration, settings.calibration_name
    key = ("default", tuple(size_wh))
    if key not in _WORKER_CACHE:
        from lfring.calibration.defaults import default_calibration

        _WORKER_CACHE[key] = default_calibration(tuple(size_wh))
    return _WORKER_CACHE[key]


def _refocuser(cal, cal_name: str, depth_m: float, settings: BatchSettings, view_shape):
    """Per worker process: one Refocuser per (settings, calibration, depth, frame size), reused
    for every frame (a folder of frames at one depth pays the geometry once). Keyed by content,
    not identity: every task brings its own unpickled copy of the settings."""
    from lfring.focus import Refocuser

    key = ("refocuser", settings.key(), cal_name, depth_m, tuple(view_shape))
    r = _WORKER_CACHE.get(key)
    if r is None:
        if sum(k[0] == "refocuser" for k in _WORKER_CACHE) >= 32:
            for k in [k for k in _WORKER_CACHE if k[0] == "refocuser"]:
                del _WORKER_CACHE[k]
        r = _WORKER_CACHE[key] = Refocuser(cal, depth_m, reference=settings.reference, view_shape=view_shape,
                                           interpolation=settings.interpolation)
    return r


def process_frame(input_path: str, settings: BatchSettings, outputs: dict[str, str] | None = None) -> FrameResult:
    """Run the batch pipeline on one frame; never raises for a bad frame.

    Returns a :class:`FrameResult` whose ``files`` maps each output kind of
    :meth:`BatchSettings.outputs` to the encoded file's bytes; on failure ``ok`` is False and
    ``error`` says why in one line.
    """


    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    worker = f"{socket.gethostname()}:{os.getpid()}"
    outputs = outputs if outputs is not None else settings.outputs(Path(input_path).stem)
    caught: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as wlist:
            warnings.simplefilter("always")
            files, info = _process(input_path, settings, outputs, timings)
            caught = [str(w.message) for w in wlist]
    except (LfringError, OSError, ValueError, MemoryError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        timings["total"] = time.perf_counter() - t_start
        error = msg if isinstance(exc, LfringError) else f"{type(exc).__name__}: {msg}"
        if input_path not in error:
            error = f"{input_path}: {error}"
        return FrameResult(input_path, False, timings_s=timings, error=error, worker=worker)
    except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the batch; the error is kept by name
        timings["total"] = time.perf_counter() - t_start
        return FrameResult(input_path, False, timings_s=timings, error=f"unexpected {type(exc).__name__}: {exc}", worker=worker)
    if caught:
        info["warnings"] = sorted(set(caught))
    timings["total"] = time.perf_counter() - t_start
    return FrameResult(input_path, True, files=files, info=info, timings_s=timings, worker=worker)


def _process(input_path, settings: BatchSettings, outputs, timings) -> tuple[dict[str, bytes], dict]:
    from lfring.io.demosaic import demosaic
    from lfring.io.levels import load_frame
    from lfring.io.writers import encode_file, encode_float_tiff, encode_image
    from lfring.focus import all_in_focus
    from lfring.views import split_views

    t = time.perf_counter()
    frame, notes = load_frame(input_path, pattern=settings.pattern, black_level=settings.black_level,
                              white_level=settings.white_level, calibration=settings.calibration)
    for level, message in notes:
        if level >= logging.WARNING:
            warnings.warn(message, LfringWarning, stacklevel=2)
    image = demosaic(frame)
    cal, cal_name = _worker_calibration(settings, (image.shape[1], image.shape[0]))
    cal.check_frame(image.shape, what=f"frame {input_path}")
    if settings.check_frames:
        from lfring.check import check_frame

        checked = check_frame(image, cal)
        if not checked.ok:
            raise InvalidInputError(f"{input_path}: {checked.message}")
    views = split_views(image, cal.layout)
    if not np.all(np.isfinite(views)):
        raise InvalidInputError(f"{input_path}: the frame holds NaN or infinite values")
    timings["load"] = time.perf_counter() - t
    info: dict = {"calibration": cal_name, "frame_size_px": [int(image.shape[1]), int(image.shape[0])]}
    arrays: dict[str, np.ndarray] = {}

    t = time.perf_counter()
    for z in settings.refocus_m:
        if f"refocus_{z:g}m" not in outputs:
            continue
        r = _refocuser(cal, cal_name, z, settings, views.shape[1:3])
        arrays[f"refocus_{z:g}m"] = r(views)
    timings["refocus"] = time.perf_counter() - t

    depth_res = None
    if settings.depth and ({"depth", "confidence", "depth_preview"} & set(outputs) or "all_in_focus" in outputs):
        from lfring.depth import estimate_depth

        t = time.perf_counter()
        depth_res = estimate_depth(views, cal, zmin_m=settings.zmin_m, zmax_m=settings.zmax_m, num_planes=settings.planes,
                                   reference=settings.reference, method=settings.depth_method)
        timings["depth"] = time.perf_counter() - t
        info["depth_hypotheses"] = len(depth_res.depths_m)
        info["depth_step_px"] = float(depth_res.step_px)
        ok = np.isfinite(depth_res.depth_m) & (depth_res.confidence >= settings.min_confidence)
        info["confident_fraction"] = float(ok.mean())
        if ok.any():
            info["depth_median_m"] = float(np.median(depth_res.depth_m[ok]))

    if "all_in_focus" in outputs:
        t = time.perf_counter()
        if depth_res is not None:
            zs = depth_res.depths_m
            img, _ = all_in_focus(views, cal, zs, depth_map_m=depth_res.depth_m, reference=settings.reference)
        else:
            zs = list(settings.refocus_m) if len(settings.refocus_m) > 1 else None
            img, _ = all_in_focus(views, cal, zs, reference=settings.reference)
        arrays["all_in_focus"] = img
        timings["all_in_focus"] = time.perf_counter() - t

    # Encode in memory and hand back bytes: the caller (maybe on another machine) does the only
    # writes into OUTDIR.
    t = time.perf_counter()
    files: dict[str, bytes] = {}
    for kind, img in arrays.items():
        files[kind] = encode_file(encode_image(img, settings.bit_depth, settings.encoding), Path(outputs[kind]).suffix)
    if depth_res is not None:
        if "depth" in outputs:
            files["depth"] = encode_float_tiff(depth_res.depth_m)
        if "confidence" in outputs:
            files["confidence"] = encode_float_tiff(depth_res.confidence)
        if "depth_preview" in outputs:
            files["depth_preview"] = _depth_preview_png(depth_res, settings, Path(input_path).name)
    timings["encode"] = time.perf_counter() - t
    if settings.viewer:
        from lfring.viewer import viewer_html

        t = time.perf_counter()
        files["viewer"] = viewer_html(views, cal, zmin_m=settings.zmin_m, zmax_m=settings.zmax_m, reference=settings.reference,
                                      depth=depth_res, num_planes=None if depth_res is not None else settings.planes,
                                      min_confidence=settings.min_confidence, title=Path(input_path).name,
                                      metadata={"input": str(input_path), "calibration": cal_name}).encode("utf-8")
        timings["viewer"] = time.perf_counter() - t
    missing = set(outputs) - set(files)
    if missing:  # pragma: no cover - a programming error, not a bad frame
        raise RuntimeError(f"outputs not produced: {sorted(missing)}")
    return files, info


def _depth_preview_png(depth_res, settings: BatchSettings, name: str) -> bytes:
    """The depth preview's PNG bytes, made in memory."""
    from lfring.depth.io import depth_preview_png

    return depth_preview_png(depth_res.depth_m, confidence=depth_res.confidence, zmin_m=settings.zmin_m,
                             zmax_m=settings.zmax_m, title=f"{name}: depth (m)", min_confidence=settings.min_confidence)


# -- the run -------------------------------------------------------------------------------------
@dataclass
class BatchReport:
    """The outcome of :func:`run_batch`.

    ``done``, ``skipped`` and ``failed`` are input paths; ``errors`` maps each failed input to
    its one-line error; ``not_frames`` lists (path, reason) of files in folder inputs left out
    because they are not frames; ``elapsed_s`` is the wall time; ``frames_per_s`` counts processed
    (not skipped) frames.
    """

    outdir: str
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    elapsed_s: float = 0.0
    manifest: str = ""
    not_frames: list = field(default_factory=list)

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
        n = len(self.done) + len(self.skipped) + len(self.failed)
        rate = f", {self.frames_per_s:.2f} frames/s" if self.done else ""
        left = f"; {len(self.not_frames)} files that are not frames left out" if self.not_frames else ""
        return (f"{n} frames: {len(self.done)} done, {len(self.skipped)} skipped (already done), "
                f"{len(self.failed)} failed in {self.elapsed_s:.1f} s{rate}; outputs in {self.outdir}{left}")


def _file_identity(path: str) -> dict:
    st = os.stat(path)
    return {"size_bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def _read_record(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("lfring_batch_record") == RECORD_VERSION else None


class _Writer:
    """The only writer into OUTDIR: temporary files in OUTDIR/.lfring-tmp, renamed into place."""

    def __init__(self, outdir: Path):
        self.outdir = outdir
        self.tmp = outdir / TMP_DIR

    def write(self, rel: str, data: bytes) -> Path:
        return atomic_write_bytes(self.outdir / rel, data, tmp_dir=self.tmp)

    def write_json(self, rel: str, obj) -> Path:
        return self.write(rel, (json.dumps(obj, indent=2, default=json_default) + "\n").encode("utf-8"))


@contextlib.contextmanager
def _outdir_lock(outdir: Path) -> Iterator[None]:
    """One batch at a time per output folder; a lock left by a killed run is taken over."""
    lock = outdir / LOCK_FILE
    me = {"pid": os.getpid(), "host": socket.gethostname()}
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                other = json.loads(lock.read_text())
            except (OSError, ValueError):
                other = {}
            alive = False
            if other.get("host") == me["host"] and isinstance(other.get("pid"), int):
                try:
                    os.kill(other["pid"], 0)
                    alive = True
                except ProcessLookupError:
                    alive = False
                except PermissionError:
                    alive = True
            elif other.get("host") not in (None, me["host"]):
                alive = True  # cannot tell from here: refuse rather than clash
            if alive:
                raise InvalidInputError(
                    f"{outdir} is in use by another lfring batch (pid {other.get('pid')} on {other.get('host')}); "
                    f"wait for it, or remove {lock} if that run is gone")
            log.info("%s: taking over the lock of a run that is gone (pid %s)", outdir, other.get("pid"))
            with contextlib.suppress(FileNotFoundError):
                lock.unlink()
            continue
        with os.fdopen(fd, "w") as f:
            json.dump(me, f)
        break
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()


def _append_manifest(path: Path, entry: dict) -> None:
    line = (json.dumps(entry, default=json_default, allow_nan=False) + "\n").encode("utf-8")
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)  # one write with O_APPEND: whole lines, even with a reader tailing it
    finally:
        os.close(fd)


def read_manifest(path: str | Path) -> list[dict]:
    """The manifest's entries (a line cut short by a killed run is left out)."""
    out = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def _init_worker(threads: int) -> None:
    import cv2

    cv2.setNumThreads(max(1, int(threads)))


class _InProcess:
    """Runs the frames one by one here (workers=1): no process start-up, same code path."""

    def submit(self, fn, *args):
        from concurrent.futures import Future

        fut: Future = Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future like a pool does
            fut.set_exception(exc)
        return fut

    def shutdown(self, **kwargs):
        pass


def _local_executor(workers: int):
    import multiprocessing as mp

    if workers == 1:
        return _InProcess(), wait
    threads = max(1, (os.cpu_count() or 1) // workers)
    # spawn, not fork: forking a process whose OpenCV thread pool is running can deadlock.
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                               initargs=(threads,))
    return pool, wait


def _dask_client(workers: int, scheduler: str | None):
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InvalidInputError(f"--executor dask needs dask.distributed, which is not installed; {_DASK_HINT}") from None
    # The cluster's own chatter (workers starting, connections) only when lfring is verbose.
    logging.getLogger("distributed").setLevel(max(logging.WARNING, log.getEffectiveLevel()))
    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InvalidInputError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
        return client, None
    import dask

    # Dask's nannies start workers with MALLOC_TRIM_THRESHOLD_ set, which freezes glibc's mmap
    # threshold: every large NumPy temporary is then mapped and unmapped afresh, and the plane
    # sweep ran 2.3x slower than in a plain process. Workers of this local cluster keep glibc's
    # adaptive default.
    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ") or {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=":0")
    client = Client(cluster)
    # As in the local pool: the cores are shared among the worker processes, not oversubscribed.
    client.run(_init_worker, max(1, (os.cpu_count() or 1) // workers))
    return client, cluster


class _DaskExecutor:
    def __init__(self, client):
        self.client = client

    def submit(self, fn, *args):
        return self.client.submit(fn, *args, pure=False)

    def shutdown(self, **kwargs):
        pass


def _dask_wait(futures, return_when=FIRST_COMPLETED):
    from distributed import wait as dwait

    res = dwait(list(futures), return_when="FIRST_COMPLETED")
    return res.done, res.not_done


@dataclass(frozen=True)
class ResumeDecision:
    """What to do with one frame of a run: ``action`` 'run' (compute ``kinds``), 'skip'
    (everything asked for is done) or 'refuse' (``reason`` says why and how to go on)."""

    action: str
    kinds: tuple[str, ...] = ()
    reason: str = ""


def decide_resume(planned: dict[str, str], planned_keys: dict[str, str], record: dict | None, identity: dict,
                  existing: frozenset | set, *, record_exists: bool, overwrite: bool, settings_key: str = "") -> ResumeDecision:
    """Decide, without touching any file, what a run does with one frame.

    Parameters
    ----------
    planned : {kind: relative path}
        The outputs this run asks for.
    planned_keys : {kind: key}
        :meth:`BatchSettings.output_keys` of this run.
    record : dict or None
        The frame's record from an earlier run (None: none, or unreadable).
    identity : dict
        The input's size and modification time now.
    existing : set of str
        Relative paths in OUTDIR that exist.
    record_exists : bool
        A file stands where the record goes (even one that is not a record).
    overwrite : bool
    settings_key : str
        :meth:`BatchSettings.legacy_key`, for records written before per-output keys.

    Returns
    -------
    ResumeDecision
        'run' with only the outputs that are missing or made with other settings by a run that
        was cut short; 'skip' when all are done with these settings on this input; 'refuse'
        for files this tool did not make, files made with other settings, or a changed input
        (unless ``overwrite``).

    Examples
    --------
    >>> done = {"outputs": {"refocus_0.5m": "a_refocus_0.5m.png"}, "output_keys": {"refocus_0.5m": "k5"},
    ...         "input_identity": {"size_bytes": 1}, "status": "done"}
    >>> decide_resume({"refocus_0.5m": "a_refocus_0.5m.png", "refocus_1m": "a_refocus_1m.png"},
    ...               {"refocus_0.5m": "k5", "refocus_1m": "k1"}, done, {"size_bytes": 1}, {"a_refocus_0.5m.png"},
    ...               record_exists=True, overwrite=False)
    ResumeDecision(action='run', kinds=('refocus_1m',), reason='')
    """
    kinds = tuple(planned)
    if overwrite:
        return ResumeDecision("run", kinds)
    present = [rel for rel in planned.values() if rel in existing]
    if record is None:
        if present or record_exists:
            what = present[0] if present else "its record"
            return ResumeDecision("refuse", reason=f"{what} exists and was not made by lfring batch; pass --overwrite to replace it")
        return ResumeDecision("run", kinds)
    ours = dict(record.get("outputs") or {})
    done_keys = dict(record.get("output_keys") or {})
    pending_keys = dict(record.get("pending_keys") or {})
    if "output_keys" not in record and record.get("settings_key") == settings_key:
        # A record from before per-output keys: its outputs were made with one settings key.
        same = {k: planned_keys[k] for k in ours if k in planned_keys}
        done_keys, pending_keys = (same, {}) if record.get("status") == "done" else ({}, same)
    if record.get("input_identity") != identity:
        if present:
            return ResumeDecision("refuse", reason=f"outputs exist ({present[0]}...) and the input changed since; "
                                                   "pass --overwrite to replace them")
        return ResumeDecision("run", kinds)
    todo = tuple(k for k in kinds if not (done_keys.get(k) == planned_keys[k] and ours.get(k) == planned[k]
                                          and planned[k] in existing))
    if not todo:
        return ResumeDecision("skip")
    owner = {rel: k for k, rel in ours.items()}
    for k in todo:
        rel = planned[k]
        if rel not in existing:
            continue
        if rel not in owner:
            return ResumeDecision("refuse", reason=f"{rel} exists and was not made by lfring batch; pass --overwrite to replace it")
        if pending_keys.get(owner[rel]) != planned_keys[k]:
            return ResumeDecision("refuse", reason=f"outputs exist ({rel}...) and other settings made them (or an "
                                                   "earlier lfring's default depth cost); pass --overwrite to replace them")
        # else: our own run with these settings, cut short: its file may be replaced
    return ResumeDecision("run", todo)


@dataclass
class _Run:
    """The state of one run shared by its steps."""

    out: Path
    settings: BatchSettings
    plan: dict
    report: BatchReport
    run_id: str
    writer: _Writer
    on_result: Callable[[dict], None] | None
    identity: dict = field(default_factory=dict)
    todo_kinds: dict = field(default_factory=dict)  # input -> kinds computed this run
    carried: dict = field(default_factory=dict)  # input -> (outputs, output_keys) of earlier runs still valid

    def entry(self, job: BatchJob, status: str, **kw) -> dict:
        kinds = self.todo_kinds.get(job.input, tuple(self.plan[job.input]))
        e = {"run": self.run_id, "input": job.input, "status": status,
             "outputs": [self.plan[job.input][k] for k in kinds], "record": job.stem + RECORD_SUFFIX,
             "settings_key": self.settings.key(), **kw}
        _append_manifest(self.out / MANIFEST, e)
        if self.on_result is not None:
            self.on_result(e)
        return e

    def record(self, job: BatchJob, status: str, **extra) -> None:
        outputs, keys = self.carried.get(job.input, ({}, {}))
        kinds = self.todo_kinds.get(job.input, tuple(self.plan[job.input]))
        planned_keys = self.settings.output_keys()
        new = {k: planned_keys[k] for k in kinds}
        self.writer.write_json(job.stem + RECORD_SUFFIX, {
            "lfring_batch_record": RECORD_VERSION, "status": status, "run": self.run_id, "input": job.input,
            "input_identity": self.identity[job.input], "settings_key": self.settings.key(),
            "settings": self.settings.describe(), "outputs": {**outputs, **self.plan[job.input]},
            "output_keys": {**keys, **new} if status == "done" else keys,
            "pending_keys": {} if status == "done" else new, "lfring_version": _version(), **extra})

    def fail(self, job: BatchJob, error: str, record_it: bool = False, **kw) -> None:
        self.report.failed.append(job.input)
        self.report.errors[job.input] = error
        log.error("%s", error if error.startswith(job.input) else f"{job.input}: {error}")
        if record_it:  # our pending record becomes a failed one (a rerun tries the frame again)
            with contextlib.suppress(OSError):
                self.record(job, "failed", error=error)
        self.entry(job, "failed", error=error, **kw)


def _check_run_args(executor, scheduler, workers, settings, out: Path) -> int:
    if executor not in EXECUTORS:
        raise InvalidInputError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if scheduler and executor != "dask":
        raise InvalidInputError("a scheduler address goes with executor='dask' (--executor dask)")
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidInputError(f"workers must be an integer >= 1, got {workers!r}")
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


def _decide_jobs(run: _Run, jobs: Sequence[BatchJob], overwrite: bool) -> list[BatchJob]:
    """Apply :func:`decide_resume` to every frame: skipped and refused frames are reported, the
    rest returned with the outputs each must compute in ``run.todo_kinds``."""
    planned_keys = run.settings.output_keys()
    todo: list[BatchJob] = []
    for job in jobs:
        outs = run.plan[job.input]
        rec_path = run.out / (job.stem + RECORD_SUFFIX)
        rec = _read_record(rec_path)
        try:
            ident = run.identity[job.input] = _file_identity(job.input)
        except OSError as exc:
            run.fail(job, f"cannot read the input: {exc.strerror or exc}")
            continue
        existing = {rel for rel in outs.values() if (run.out / rel).exists()}
        d = decide_resume(outs, planned_keys, rec, ident, existing, record_exists=rec_path.exists(), overwrite=overwrite,
                          settings_key=run.settings.legacy_key() or "")
        if d.action == "refuse":
            run.fail(job, d.reason)
            continue
        if d.action == "skip":
            run.report.skipped.append(job.input)
            run.todo_kinds[job.input] = ()
            run.entry(job, "skipped")
            continue
        run.todo_kinds[job.input] = d.kinds
        if rec is not None and rec.get("input_identity") == ident:
            keep = {k: v for k, v in (rec.get("output_keys") or {}).items() if k not in d.kinds}
            run.carried[job.input] = ({k: v for k, v in (rec.get("outputs") or {}).items() if k in keep}, keep)
        todo.append(job)
    return todo


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
    if not res.ok:
        run.fail(job, res.error, record_it=True, timings_s=res.timings_s, worker=res.worker)
        return
    t_w = time.perf_counter()
    try:
        for kind in run.todo_kinds[job.input]:
            run.writer.write(run.plan[job.input][kind], res.files[kind])
        run.record(job, "done", info=res.info, timings_s=res.timings_s)
    except OSError as exc:
        run.fail(job, f"cannot write its outputs: {exc.strerror or exc}", record_it=True)
        return
    res.timings_s["write"] = time.perf_counter() - t_w
    run.report.done.append(job.input)
    run.entry(job, "done", timings_s=res.timings_s, worker=res.worker, info=res.info)
    for w in res.info.get("warnings", []):
        log.warning("%s: %s", job.input, w)


def _execute(run: _Run, todo: list[BatchJob], *, workers: int, executor: str, scheduler, progress) -> None:
    """Process the frames on the executor, a window of them at a time; a lost local worker's
    frames are retried once on a fresh pool."""
    bar = _progress(todo, progress)
    cluster = client = None
    pool = None
    try:
        if todo:
            if executor == "dask":
                client, cluster = _dask_client(workers, scheduler)
                pool, waiter = _DaskExecutor(client), _dask_wait
            else:
                pool, waiter = _local_executor(min(workers, len(todo)))
        window = max(2, 2 * workers)
        pending: dict = {}
        queue = list(todo)
        retried: set[str] = set()

        def submit(job: BatchJob) -> None:
            run.record(job, "pending")
            outputs = {k: run.plan[job.input][k] for k in run.todo_kinds[job.input]}
            pending[pool.submit(process_frame, job.input, run.settings, outputs)] = job

        while queue or pending:
            while queue and len(pending) < window:
                job = queue.pop(0)
                try:
                    submit(job)
                except OSError as exc:
                    run.fail(job, f"cannot write its record: {exc}")
            if not pending:
                continue
            done_set, _ = waiter(list(pending), return_when=FIRST_COMPLETED)
            for fut in done_set:
                job = pending.pop(fut)
                try:
                    res: FrameResult = fut.result()
                except Exception as exc:  # noqa: BLE001 - a worker died (crash, killed): retry once elsewhere
                    if job.input not in retried and executor == "local" and not isinstance(pool, _InProcess):
                        retried.add(job.input)
                        log.warning("%s: worker lost (%s); retrying once", job.input, type(exc).__name__)
                        pool.shutdown(wait=False, cancel_futures=True)
                        requeue = [job, *pending.values()]
                        pending.clear()
                        pool, waiter = _local_executor(min(workers, len(requeue) + len(queue)))
                        queue[:0] = requeue
                        break
                    run.fail(job, f"the worker processing it was lost: {type(exc).__name__}: {exc}", record_it=True)
                    if bar is not None:
                        bar.update(1)
                    continue
                _finish(run, job, res)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(failed=len(run.report.failed), refresh=False)
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
        Redo frames already done and replace files this run did not make.
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
        Bad arguments, no inputs, outputs that would collide: nothing is processed.

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
    >>> with tempfile.TemporaryDirectory() as out:
    ...     first = run_batch(["data/synthetic/scene.png"], out, BatchSettings(refocus_m=(0.5,)), workers=1, progress=False)
    ...     again = run_batch(["data/synthetic/scene.png"], out, BatchSettings(refocus_m=(0.5,)), workers=1, progress=False)
    ...     files = sorted(os.listdir(out))
    >>> first.exit_code, len(first.done), len(again.done), len(again.skipped)
    (0, 1, 0, 1)
    >>> files
    ['manifest.jsonl', 'scene.lfring.json', 'scene_refocus_0.5m.png']
    """
    out = Path(outdir)
    workers = _check_run_args(executor, scheduler, workers, settings, out)
    jobs, not_frames = scan_inputs(inputs, outdir=out, exclude=exclude, frame_sizes=_frame_sizes(settings))
    plan = plan_jobs(jobs, settings, out)
    out.mkdir(parents=True, exist_ok=True)
    report = BatchReport(str(out), manifest=str(out / MANIFEST), not_frames=not_frames)
    t0 = time.perf_counter()
    run_id = time.strftime("%Y%m%dT%H%M%S") + f"-{os.getpid()}"
    with _outdir_lock(out):
        writer = _Writer(out)
        # Temporary files left by a killed run are never outputs; clear them.
        if writer.tmp.exists():
            shutil.rmtree(writer.tmp, ignore_errors=True)
        run = _Run(out, settings, plan, report, run_id, writer, on_result)
        try:
            todo = _decide_jobs(run, jobs, overwrite)
            _execute(run, todo, workers=workers, executor=executor, scheduler=scheduler, progress=progress)
        finally:
            shutil.rmtree(writer.tmp, ignore_errors=True)
    report.elapsed_s = time.perf_counter() - t0
    return report


def _version() -> str:
    from lfring import __version__

    return __version__
