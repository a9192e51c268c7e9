"""Which files a batch processes: files, folders (searched recursively) and glob patterns
expanded into :class:`BatchJob` items, with the files of folders that are not frames left out
and said why, and the output names of every job checked before anything runs."""

from __future__ import annotations

import fnmatch
import glob
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lfring.batch.record import RECORD_SUFFIX
from lfring.batch.settings import BatchSettings
from lfring.errors import InvalidInputError
from lfring.io.readers import frame_size

__all__ = ["TRUTH_SUFFIX", "WRONG_SIZE", "BatchJob", "find_inputs", "frame_size", "plan_jobs", "scan_inputs"]

log = logging.getLogger("lfring.batch")


def _frame_suffixes() -> frozenset[str]:
    from lfring.io.raw import RAW_SUFFIXES

    return frozenset(RAW_SUFFIXES) | {".png", ".tif", ".tiff"}


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
WRONG_SIZE = "a size no calibration fits"
"""How a folder's PNG/TIFF of a size no calibration of the run reads is listed among the files left out."""


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
    wrong_size: list[tuple[str, tuple[int, int]]] = []  # (path, size) of the folder files left out for their size

    patterns = {pat: os.path.normpath(pat) for pat in exclude}
    matched: set[str] = set()

    def excluded(rel: str, given: Path | None = None) -> bool:
        """Whether a pattern matches the file's name, its path below its folder argument or its
        path as given (``in/hard.png``)."""
        names = (rel, Path(rel).name, *(() if given is None else (os.path.normpath(given),)))
        hit = [pat for pat, norm in patterns.items() if any(fnmatch.fnmatch(n, pat) or fnmatch.fnmatch(n, norm)
                                                              for n in names)]
        matched.update(hit)
        return bool(hit)

    def keep(p: Path) -> bool:
        return out_res is None or not _is_under(p.resolve(), out_res)

    for arg in inputs:
        arg = str(arg)
        p = Path(arg)
        if p.exists() and not keep(p):
            raise InvalidInputError(
                f"{arg} lies in the output folder {outdir}: a batch never reads its output folder (a rerun would take "
                "its outputs for frames); give another output folder")
        if p.is_dir():
            n0, n_sized = len(found), len(wrong_size)
            for root, dirs, files in os.walk(p):
                for d in sorted(dirs):
                    if d.endswith(TRUTH_SUFFIX) and not d.startswith("."):
                        skipped.append((str(Path(root, d)) + os.sep, "a ground-truth folder"))
                dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not d.endswith(TRUTH_SUFFIX) and keep(Path(root, d)))
                for name in sorted(files):
                    f = Path(root, name)
                    rel = f.relative_to(p).as_posix()
                    if name.startswith(".") or not keep(f) or excluded(rel, f):
                        continue
                    if f.suffix.lower() not in suffixes:
                        if f.suffix.lower() == ".json":
                            skipped.append((str(f), "a sidecar or record (JSON)"))
                        continue
                    if f.exists() and not f.is_file():  # a named pipe would wait for a writer
                        skipped.append((str(f), "not a regular file"))
                        continue
                    if sizes is not None:
                        size = frame_size(f)
                        if size == (0, 0):
                            skipped.append((str(f), "float samples (a map, not raw counts)"))
                            continue
                        if size is not None and size not in sizes:
                            skipped.append((str(f), f"{size[0]} x {size[1]} px, {WRONG_SIZE}"))
                            wrong_size.append((str(f), size))
                            continue
                    found.append((f, rel))
            if len(found) == n0:
                if len(wrong_size) > n_sized:
                    log.warning("%s: no frames of a size a calibration fits (%s); %d left out for their size",
                                arg, _sizes_words(sizes), len(wrong_size) - n_sized)
                else:
                    log.warning("%s: no frames found (suffixes %s)", arg, ", ".join(sorted(suffixes)))
        elif p.is_file():
            if not excluded(p.name, p):
                found.append((p, p.name))
        elif p.exists():
            raise InvalidInputError(f"{arg}: not a regular file (a named pipe or a device); give frame files or folders")
        elif glob.has_magic(arg):
            matches = sorted(glob.glob(arg, recursive=True))
            files = [Path(m) for m in matches if Path(m).is_file()]
            files = [f for f in files if keep(f) and not excluded(f.name, f) and not f.name.endswith(".json")]
            if not files:
                raise InvalidInputError(f"{arg}: the pattern matches no files")
            found.extend((f, f.name) for f in files)
        else:
            raise InvalidInputError(f"{arg}: no such file or folder")
    for pat in exclude:
        if pat not in matched:
            log.warning("exclude pattern %r matched no input file (patterns match a file's name, its path below its "
                        "folder, or its path as given)", pat)
    # The same file named twice (a folder and a glob, a link beside its target) is one job: the
    # file itself where a link to it was found too (its sidecar and name are the frame's).
    seen: dict[Path, tuple[Path, BatchJob]] = {}
    for f, rel in found:
        res = f.resolve()
        stem = rel[: -len(Path(rel).suffix)] if Path(rel).suffix else rel
        if res not in seen or (seen[res][0].is_symlink() and not f.is_symlink()):
            if res in seen:
                log.info("%s is a link to %s: processed once, as %s", seen[res][0], f, f)
            seen[res] = (f, BatchJob(str(f), stem))
        elif f != seen[res][0]:
            log.info("%s is the same file as %s: processed once", f, seen[res][0])
    jobs = [job for _, job in seen.values()]
    if not jobs:
        more = ""
        if wrong_size:
            (path, (w, h)), n, several = wrong_size[0], len(wrong_size), len(sizes) > 1
            more = (f": {n} file{'s' * (n > 1)} left out for a size no calibration fits, as {path} ({w} x {h} px); "
                    f"the calibration{'s' * several} of this run read{'' if several else 's'} frames of "
                    f"{_sizes_words(sizes)}")
        raise InvalidInputError(f"no frames found in {', '.join(map(str, inputs))}{more}")
    return jobs


def _sizes_words(sizes) -> str:
    """The frame sizes a run reads, in words."""
    return " or ".join(f"{w} x {h} px" for w, h in sorted(sizes or ()))


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
