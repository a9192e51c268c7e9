"""What a batch keeps in its output folder, and what a rerun makes of it: the per-frame record,
the manifest, the one writer into OUTDIR, the folder's lock and the resume decision.

A frame's record ``<name>.lfring.json`` is written ``pending`` before its outputs and ``done``
after them; its ``outputs`` are the frame's files that exist (the files a pending or failed run
was to write are its ``planned_outputs``). :func:`decide_resume` reads it, with the input's
identity (size and modification time, and a digest of its content, taken when the record is
written and compared only when the time differs: a folder copied without its times is still the
same frames), to skip what is done, compute only what is missing and refuse files this tool did
not make. The single-frame commands keep a record of the same form per output set
(:mod:`lfring.cli.outputs`).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from lfring.core.signals import held_signals
from lfring.errors import InvalidInputError
from lfring.io.atomic import atomic_write_bytes
from lfring.io.raw import sidecar_path
from lfring.io.readers import RECORD_KEY
from lfring.io.writers import json_default

__all__ = [
    "LOCK_FILE",
    "MANIFEST",
    "RECORD_SUFFIX",
    "RECORD_VERSION",
    "TMP_DIR",
    "OutputWriter",
    "ResumeDecision",
    "DIGEST_KEY",
    "append_manifest",
    "as_recorded",
    "content_digest",
    "decide_resume",
    "file_identity",
    "input_identity",
    "is_batch_manifest",
    "made_with",
    "outdir_lock",
    "read_manifest",
    "read_record",
    "same_input",
]

log = logging.getLogger("lfring.batch")

TMP_DIR = ".lfring-tmp"
LOCK_FILE = ".lfring-batch.lock"
MANIFEST = "manifest.jsonl"
RECORD_SUFFIX = ".lfring.json"
RECORD_VERSION = 1
MANIFEST_ENTRY_KEYS = ("run", "input", "status")
"""Keys every line of a batch's manifest holds, since its first version: a file whose lines
lack them is not a batch's manifest, and is neither appended to nor replaced unasked."""


# A file's identity in a record holds its content's digest under this key (BLAKE2b, 128 bits, hex).
DIGEST_KEY = "blake2b"
_CHUNK = 1 << 20
# Digests read in this process, by (real path, size, modification time): a run that checks a
# frame and then records it reads it once. The oldest go past DIGESTS_KEPT.
_DIGESTS: dict = {}
DIGESTS_KEPT = 4096


def _digest_key(path) -> tuple:
    st = os.stat(path)
    return os.path.realpath(path), st.st_size, st.st_mtime_ns


def _keep_digest(key: tuple, digest: str) -> str:
    _DIGESTS[key] = digest
    while len(_DIGESTS) > DIGESTS_KEPT:
        del _DIGESTS[next(iter(_DIGESTS))]
    return digest


def content_digest(path: str | Path) -> str:
    """The BLAKE2b (128-bit) digest of the file at ``path``, hex."""
    key = _digest_key(path)
    found = _DIGESTS.get(key)
    if found is None:
        h = hashlib.blake2b(digest_size=16)
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(_CHUNK), b""):
                h.update(chunk)
        found = _keep_digest(key, h.hexdigest())
    return found


def file_identity(path: str | Path, *, digest: bool = False) -> dict:
    """A file's size and modification time, with ``digest`` its content's
    (:func:`content_digest`, under :data:`DIGEST_KEY`): a record made from another identity is
    stale. Records keep the digest; a check reads it only when the time differs."""
    st = os.stat(path)
    out = {"size_bytes": st.st_size, "mtime_ns": st.st_mtime_ns}
    if digest:
        out[DIGEST_KEY] = content_digest(path)
    return out


def _same_file(recorded, now: dict, path) -> bool:
    """Whether the file ``now`` (:func:`file_identity` without digest, at ``path``) is the one
    ``recorded``: the same size and time, or the same size and, where the record keeps a digest
    and the file can be read, the same content (a copy that did not keep the times)."""
    if not isinstance(recorded, dict):
        return False
    if all(recorded.get(k) == v for k, v in now.items() if k != DIGEST_KEY):
        return True
    if path is None or DIGEST_KEY not in recorded or recorded.get("size_bytes") != now.get("size_bytes"):
        return False
    try:
        return content_digest(path) == recorded[DIGEST_KEY]
    except OSError:
        return False


def as_recorded(made: dict, rel: str, path: str | Path) -> bool:
    """Whether the file at ``path`` is as a record's ``output_identity`` (``made``) found it
    under ``rel``: not written since by another command or by hand."""
    try:
        return rel in made and _same_file(made[rel], file_identity(path), path)
    except OSError:
        return False


def input_identity(path: str, *, digest: bool = False) -> dict:
    """An input's :func:`file_identity`, with its sidecar's under ``sidecar`` (None without one):
    the sidecar gives the pattern and levels a frame is read with, so a changed sidecar is a
    changed input. ``digest``: with the contents' digests, as records keep them."""
    out = file_identity(path, digest=digest)
    side = sidecar_path(path)
    out["sidecar"] = file_identity(side, digest=digest) if side.is_file() else None
    return out


def same_input(recorded, now, path: str | None = None) -> bool:
    """Whether an input's identity ``now`` (:func:`input_identity` of the file at ``path``, or a
    dict of them by path) is the one a record holds. Where only the times differ, the digests
    the record keeps are compared with the files' (with ``path``; the keys of a dict by path are
    the paths). A record written before sidecars were counted (no ``sidecar`` key) is judged on
    the file alone."""
    if not (isinstance(recorded, dict) and isinstance(now, dict)):
        return recorded == now
    if "size_bytes" not in now:  # identities by path
        return set(recorded) == set(now) and all(same_input(recorded[k], now[k], k) for k in now)
    if not _same_file(recorded, {k: v for k, v in now.items() if k != "sidecar"}, path):
        return False
    if "sidecar" not in recorded:
        return True
    side, was = now.get("sidecar"), recorded["sidecar"]
    if side is None or was is None:
        return side is None and was is None
    return _same_file(was, side, None if path is None else sidecar_path(path))


def made_with(record: dict, kind_or_run: str, *, run: bool = True) -> dict | None:
    """The settings of the run ``kind_or_run`` as a frame's ``record`` holds them (its own run's,
    or an earlier one's that made an output it keeps), or, with ``run=False``, those that made
    the output of that kind; None when the record does not tell. A record of a version before
    outputs named their runs gives its own settings for every output.

    Examples
    --------
    >>> from lfring.batch.record import made_with
    >>> rec = {"run": "r2", "settings": {"aperture": 2.0}, "output_runs": {"a": "r1", "b": "r2"},
    ...        "earlier_settings": {"r1": {"aperture": 1.0}}}
    >>> made_with(rec, "a", run=False), made_with(rec, "b", run=False), made_with(rec, "r3")
    ({'aperture': 1.0}, {'aperture': 2.0}, None)
    """
    if not run:
        runs = record.get("output_runs")
        if not isinstance(runs, dict) or kind_or_run not in runs:
            return record.get("settings") if isinstance(record.get("settings"), dict) else None
        kind_or_run = runs[kind_or_run]
    if kind_or_run == record.get("run"):
        found = record.get("settings")
    else:
        found = (record.get("earlier_settings") or {}).get(kind_or_run)
    return found if isinstance(found, dict) else None


def read_record(path: Path) -> dict | None:
    """The record at ``path``, or None when there is none, it is unreadable or of another version."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get(RECORD_KEY) == RECORD_VERSION else None


class OutputWriter:
    """The only writer into OUTDIR: temporary files in OUTDIR/.lfring-tmp, renamed into place."""

    def __init__(self, outdir: Path):
        self.outdir = outdir
        self.tmp = outdir / TMP_DIR

    def write(self, rel: str, data: bytes) -> Path:
        """Write ``data`` atomically to ``rel`` (relative to OUTDIR); its digest, taken from the
        bytes in hand, is what :func:`content_digest` gives for the file (a record's identity of
        it needs no second read)."""
        path = atomic_write_bytes(self.outdir / rel, data, tmp_dir=self.tmp)
        with contextlib.suppress(OSError):
            _keep_digest(_digest_key(path), hashlib.blake2b(data, digest_size=16).hexdigest())
        return path

    def write_json(self, rel: str, obj) -> Path:
        """Write ``obj`` as indented JSON, atomically, to ``rel`` (relative to OUTDIR)."""
        return atomic_write_bytes(self.outdir / rel, (json.dumps(obj, indent=2, default=json_default) + "\n").encode("utf-8"),
                                  tmp_dir=self.tmp)


@contextlib.contextmanager
def outdir_lock(outdir: Path) -> Iterator[None]:
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
        with held_signals(), contextlib.suppress(FileNotFoundError):  # a stop now waits for the unlink
            lock.unlink()


def append_manifest(path: Path, entry: dict) -> None:
    """Append ``entry`` to the manifest at ``path`` as one JSON line. A line cut short by a full
    disk is taken back (an OSError naming the file says why); one an earlier run left without
    its end is ended first, so that this line stays a line of its own."""
    line = (json.dumps(entry, default=json_default, allow_nan=False) + "\n").encode("utf-8")
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        size = os.fstat(fd).st_size
        if size and os.pread(fd, 1, size - 1) != b"\n":
            line = b"\n" + line
        try:
            written = os.write(fd, line)  # one write with O_APPEND: whole lines, even with a reader tailing it
        except OSError as exc:
            written, error = 0, exc
        else:
            error = None
        if written != len(line):
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            err = error.errno if error is not None else errno.ENOSPC
            why = error.strerror if error is not None else "the disk is full"
            raise OSError(err, f"cannot append to {path}: {why}")
    finally:
        os.close(fd)


def is_batch_manifest(path: str | Path) -> bool:
    """Whether the file at ``path`` is a manifest that lfring batch wrote: empty, or JSON lines
    that are all entries with :data:`MANIFEST_ENTRY_KEYS` (lines that do not parse, which a
    killed run can leave, aside), at least one of them.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from lfring.batch.record import is_batch_manifest
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = pathlib.Path(d, "manifest.jsonl")
    ...     _ = p.write_text('{"run": "r1", "input": "a.png", "status": "done", "outputs": []}\\n')
    ...     ours = is_batch_manifest(p)
    ...     _ = p.write_text('{"id": 1, "label": "cat"}\\n')
    ...     ours, is_batch_manifest(p)
    (True, False)
    """
    try:
        data = Path(path).read_bytes()
    except OSError:  # a folder, or unreadable: not one to append to
        return False
    if not data.strip():
        return True
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    entries = 0
    for line in text.splitlines():
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except ValueError:
            continue  # cut short by a killed run
        if not (isinstance(entry, dict) and all(k in entry for k in MANIFEST_ENTRY_KEYS)):
            return False
        entries += 1
    return entries > 0


def read_manifest(path: str | Path) -> list[dict]:
    """The manifest's entries (a line cut short by a killed run is left out)."""
    out = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


@dataclass(frozen=True)
class ResumeDecision:
    """What to do with one frame of a run: ``action`` 'run' (compute ``kinds``), 'skip'
    (everything asked for is done) or 'refuse' (``reason`` says why and how to go on)."""

    action: str
    kinds: tuple[str, ...] = ()
    reason: str = ""


def decide_resume(planned: dict[str, str], planned_keys: dict[str, str], record: dict | None, identity: dict,
                  existing: frozenset | set, *, record_exists: bool, overwrite: bool, settings_key: str = "",
                  maker: str = "lfring batch", alias_keys: dict[str, str] | None = None,
                  explain: Callable[[str, dict], list[str]] | None = None, input_path: str | None = None) -> ResumeDecision:
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
    maker : str
        The command whose records these are, as the reasons name it (the single-frame commands
        keep their output sets with the same records).
    alias_keys : {kind: key}, optional
        Keys that stand for the same outputs as ``planned_keys``, as earlier versions computed
        them (:meth:`BatchSettings.output_keys` with ``resolved=False``).
    explain : callable, optional
        ``explain(kind, record)``: what differs between the settings that made the output
        ``kind`` and this run's (:meth:`BatchSettings.differences`), for the reason of a refusal.
    input_path : str, optional
        The input's path, for :func:`same_input` to compare contents where only the times differ.

    Returns
    -------
    ResumeDecision
        'run' with only the outputs that are missing or made with other settings by a run that
        was cut short; 'skip' when all are done with these settings on this input; 'refuse'
        for files this tool did not make, files made with other settings, or a changed input
        (unless ``overwrite``).

    Examples
    --------
    >>> from lfring.batch import decide_resume
    >>> done = {"outputs": {"refocus_0.5m": "a_refocus_0.5m.png"}, "output_keys": {"refocus_0.5m": "k5"},
    ...         "input_identity": {"size_bytes": 1}, "status": "done"}
    >>> decide_resume({"refocus_0.5m": "a_refocus_0.5m.png", "refocus_1m": "a_refocus_1m.png"},
    ...               {"refocus_0.5m": "k5", "refocus_1m": "k1"}, done, {"size_bytes": 1}, {"a_refocus_0.5m.png"},
    ...               record_exists=True, overwrite=False)
    ResumeDecision(action='run', kinds=('refocus_1m',), reason='')
    """
    kinds = tuple(planned)
    alias = alias_keys or {}

    def matches(key, kind) -> bool:
        return key is not None and key in (planned_keys[kind], alias.get(kind))

    if overwrite:
        return ResumeDecision("run", kinds)
    present = [rel for rel in planned.values() if rel in existing]
    if record is None:
        if present or record_exists:
            what = present[0] if present else "its record"
            return ResumeDecision("refuse", reason=f"{what} exists and was not made by {maker}; pass overwrite=True to replace it")
        return ResumeDecision("run", kinds)
    ours = dict(record.get("outputs") or {})
    done_keys = dict(record.get("output_keys") or {})
    pending_keys = dict(record.get("pending_keys") or {})
    if "output_keys" not in record and record.get("settings_key") == settings_key:
        # A record from before per-output keys: its outputs were made with one settings key.
        same = {k: planned_keys[k] for k in ours if k in planned_keys}
        done_keys, pending_keys = (same, {}) if record.get("status") == "done" else ({}, same)
    if not same_input(record.get("input_identity"), identity, input_path):
        made_from = record.get("input")
        if (present and input_path is not None and isinstance(made_from, str)
                and os.path.realpath(made_from) != os.path.realpath(input_path)):
            return ResumeDecision("refuse", reason=f"outputs exist ({present[0]}...), made from another frame ({made_from}) "
                                                   "of the same name; pass overwrite=True to replace them, or write "
                                                   "elsewhere")
        if present:
            return ResumeDecision("refuse", reason=f"outputs exist ({present[0]}...) and the input changed since (the "
                                                   "frame or its sidecar); pass overwrite=True to replace them")
        return ResumeDecision("run", kinds)
    todo = tuple(k for k in kinds if not (matches(done_keys.get(k), k) and ours.get(k) == planned[k]
                                          and planned[k] in existing))
    if not todo:
        return ResumeDecision("skip")
    # The files of a run cut short are listed apart from the outputs (they may not exist).
    owner = {rel: k for k, rel in {**dict(record.get("planned_outputs") or {}), **ours}.items()}
    for k in todo:
        rel = planned[k]
        if rel not in existing:
            continue
        if rel not in owner:
            return ResumeDecision("refuse", reason=f"{rel} exists and was not made by {maker}; pass overwrite=True to replace it")
        if not matches(pending_keys.get(owner[rel]), k):
            what = explain(owner[rel], record) if explain is not None else []
            if what:
                return ResumeDecision("refuse", reason=(
                    f"{rel} exists, made with other settings: {'; '.join(what)}. Give the settings that made it, "
                    "leave it out of this run (its record keeps it), or pass overwrite=True to replace it"))
            return ResumeDecision("refuse", reason=f"outputs exist ({rel}...) and other settings made them (or an "
                                                   "earlier lfring made them another way: with its default depth cost "
                                                   "then, or an all-in-focus image without the depth map); pass "
                                                   "overwrite=True to replace them")
        # else: our own run with these settings, cut short: its file may be replaced
    return ResumeDecision("run", todo)
