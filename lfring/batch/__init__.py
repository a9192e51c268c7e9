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
- ``OUTDIR/manifest.jsonl`` gets one JSON line per frame and run (input, status, the outputs
  that run wrote, timings, error; a frame that failed or was left out lists none, and the
  files it was to write as ``planned_outputs``); a ``manifest.jsonl`` that a batch did not
  write is neither appended to nor replaced unless ``overwrite=True``.

The modules, in the order a run uses them:

- :mod:`lfring.batch.settings`: :class:`BatchSettings` (what to make of every frame), its checks
  and the keys that tell a rerun which outputs are still valid;
- :mod:`lfring.batch.discovery`: files, folders and glob patterns into :class:`BatchJob` items
  (:func:`find_inputs`, :func:`scan_inputs`, :func:`frame_size`, the ``*_truth/`` rule), and
  :func:`plan_jobs`, which names every output and refuses collisions;
- :mod:`lfring.batch.record`: what the output folder keeps (per-frame records, the manifest and
  :func:`read_manifest`, the one atomic writer, the folder's lock, the input's identity) and
  :func:`decide_resume`, which reads them to skip, resume or refuse a frame;
- :mod:`lfring.batch.pipeline`: :func:`process_frame`, the pipeline of one frame in a worker,
  and its :class:`FrameResult` of encoded files;
- :mod:`lfring.batch.executors`: the local process pool (or this process alone) and the Dask
  executor (:data:`EXECUTORS`);
- :mod:`lfring.batch.run`: :func:`run_batch`, the run from start to end, and its
  :class:`BatchReport`.
"""

from lfring.batch.discovery import (
    BatchJob,
    find_inputs,
    frame_size,
    plan_jobs,
    scan_inputs,
)
from lfring.batch.executors import EXECUTORS
from lfring.batch.pipeline import FrameResult, process_frame
from lfring.batch.record import ResumeDecision, decide_resume, read_manifest
from lfring.batch.run import BatchReport, run_batch
from lfring.batch.settings import BatchSettings

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
    "plan_jobs",
    "process_frame",
    "read_manifest",
    "run_batch",
    "scan_inputs",
]
