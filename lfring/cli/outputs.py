"""Every command's outputs as one set: all of them, or none.

A command names its outputs before it works (:class:`OutputSet`), writes them into a hidden
staging folder beside them (:meth:`OutputSet.writing` hands out the staged paths) and, when all
are written, renames them into place together, with Ctrl-C and SIGTERM held, and keeps a record
``<set>.lfring.json`` of what it made from which inputs with which settings: the record of
:mod:`lfring.batch.record`, read by its :func:`~lfring.batch.record.decide_resume`. An
interrupted command leaves nothing (its staging folder goes); a rerun with the same inputs and
settings replaces its own outputs; a file the command did not make, or made from other inputs
or with other settings, is replaced only with ``--overwrite``. The files of the set a run
replaces with ``--overwrite`` that it does not make again (a longer focal stack's) are removed
with it, where they are as the set's record found them: a folder never holds two sets' files
under one record.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
import socket
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import click

from lfring.batch.record import (RECORD_SUFFIX, RECORD_VERSION, as_recorded, decide_resume, file_identity, input_identity, read_record,
                                 same_input)
from lfring.core.signals import deliver_lost_stops, held_signals
from lfring.errors import InvalidInputError
from lfring.io.atomic import atomic_write_text
from lfring.io.raw import sidecar_path
from lfring.io.readers import RECORD_KEY
from lfring.io.writers import IMAGE_SUFFIXES, check_writable, json_default

__all__ = ["OUTPUT_OPTIONS", "STAGING_PREFIX", "OutputSet", "record_path"]

STAGING_PREFIX = ".lfring-stage-"
"""Hidden folders of outputs being written: ``<prefix><pid>-<random>`` in the set's folder."""

# Options that change no output: a rerun that differs only in them replaces its own outputs.
_NOT_SETTINGS = frozenset({"overwrite", "progress", "threads"})
# The commands' parameters that name where their outputs go (-o and --plot); every other
# parameter that names a file names an input.
OUTPUT_OPTIONS = frozenset({"output", "outdir", "plot"})


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Hold an exclusive lock on ``folder`` (the folder itself, no lock file), where the system
    has such locks: two commands finishing into one folder check and rename one after the other."""
    try:
        import fcntl
    except ImportError:  # no POSIX locks (Windows): the check right before the rename stands alone
        yield
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            logging.getLogger("lfring.cli").info("waiting for another lfring command writing into %s", folder)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:
                pass  # a lock the file system cannot keep: the check right before the rename stands alone
        except OSError:  # NFS without byte-range locks on folders, no lock daemon: as above
            pass
        yield
    finally:
        os.close(fd)  # releases the lock


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (a case-insensitive file system's two spellings, links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def record_path(folder: str | Path, name: str) -> Path:
    """Where the record of the output set ``name`` lies in ``folder``."""
    return Path(folder) / f"{name}{RECORD_SUFFIX}"


def _jsonable(value):
    if hasattr(value, "as_kwargs"):  # RawLevels
        return value.as_kwargs()
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def _input_files(params: dict) -> list[str]:
    """The files a command reads, among its arguments and options (paths that name files)."""
    out: list[str] = []
    for value in params.values():
        for v in value if isinstance(value, (tuple, list)) else (value,):
            if isinstance(v, (str, Path)) and str(v) and os.path.isfile(v) and str(v) not in out:
                out.append(str(v))
    return out


def _canonical(value, files: set, output: bool):
    """A parameter's value with the files it names (inputs in ``files``; any path when it is an
    ``output`` option's) as their real paths."""
    if isinstance(value, (tuple, list)):
        return [_canonical(v, files, output) for v in value]
    if isinstance(value, (str, Path)) and str(value):
        real = os.path.realpath(value)
        if output or real in files:
            return real
    return value


def _settings_key(command: str, params: dict) -> str:
    return hashlib.sha256(json.dumps({"command": command, **params}, sort_keys=True, default=str).encode()).hexdigest()[:16]


class OutputSet:
    """The outputs of one command run, written as a set.

    Parameters
    ----------
    paths : iterable of path
        Every file the command will write.
    name : str
        The set's name: its record is ``<folder of the first path>/<name>.lfring.json``.
    overwrite : bool
        Replace files the command did not make (or made from other inputs or settings).
    ctx : click.Context, optional
        The command's context (default: the current one): its name, and its parameters as the
        inputs (those that name files) and the settings of the set.
    formerly : str, optional
        The set's name in earlier versions of lfring: where this set has no record yet, a
        record of that name that lists exactly this set's outputs is this set's (read for the
        rerun's decision, and replaced by this set's record once the outputs are written).
    """

    def __init__(self, paths: Iterable, *, name: str, overwrite: bool, ctx: click.Context | None = None,
                 formerly: str | None = None):
        self.paths = [Path(p) for p in paths]
        if not self.paths:
            raise ValueError("an output set needs at least one path")
        self.folder = self.paths[0].parent
        self.record = record_path(self.folder, name)
        self._former = record_path(self.folder, formerly) if formerly and formerly != name else None
        self.overwrite = overwrite
        ctx = ctx or click.get_current_context()
        self.command = f"lfring {ctx.info_name}"
        params = {k: _jsonable(v) for k, v in sorted(ctx.params.items()) if k not in _NOT_SETTINGS}
        ours = {os.path.realpath(p) for p in [*self.paths, self.record]}
        inputs = _input_files({k: v for k, v in ctx.params.items() if k not in OUTPUT_OPTIONS})
        self._clashes = [f for f in inputs if os.path.realpath(f) in ours]
        # A frame's sidecar (its pattern and levels) is part of the input, there or not: written
        # over, or written where there was none, it would change how the frame is read.
        self._clashes += [f"{sidecar_path(f)} (the sidecar of {f})" for f in inputs
                          if Path(f).suffix.lower() in IMAGE_SUFFIXES and os.path.realpath(sidecar_path(f)) in ours]
        named = [p.opts[0] for p in ctx.command.params if p.name in OUTPUT_OPTIONS and ctx.params.get(p.name)]
        self._output_option = named[0] if named else "the output"
        self.inputs = [f for f in inputs if os.path.realpath(f) not in ours]
        self.settings = params
        # The key names files by what they are, not by how this run spelled them (scene.png,
        # ./scene.png, its absolute path); the key as earlier versions computed it, from the
        # paths as typed, still stands for their outputs.
        files = {os.path.realpath(f) for f in inputs}
        canonical = {k: _canonical(v, files, k in OUTPUT_OPTIONS) for k, v in params.items()}
        self.key = _settings_key(self.command, canonical)
        self._typed_key = _settings_key(self.command, params)
        # What the command resolved from its settings to make the outputs (the aperture an
        # f-number came to, ...): written in the record beside the settings as typed, and no part
        # of the key (the settings decide it).
        self.made_with: dict = {}
        self._root = Path(os.path.commonpath([str(p.parent.absolute()) for p in [*self.paths, self.record]]))

    def _rel(self, p: Path) -> str:
        return os.path.relpath(p.absolute(), self._root)

    def check(self) -> None:
        """Refuse, before any work, outputs that cannot be written or may not be replaced.

        Raises
        ------
        InvalidInputError
            Naming the first file and why (a folder in the way, a file this command did not make
            or made from other inputs or with other settings, without ``--overwrite``).
        """
        if self._clashes:
            raise InvalidInputError(f"{self._clashes[0]} is an input of this command and would be one of its outputs "
                                    f"(or their record): give {self._output_option} another name")
        check_writable([*self.paths, self.record], overwrite=True)
        self._clear_stale_staging()
        planned = {self._rel(p): self._rel(p) for p in self.paths}
        existing = {rel for rel in planned if (self._root / rel).exists()}
        identity = {os.path.realpath(p): input_identity(p) for p in self.inputs}
        former = self._former_record()
        rec = read_record(self.record) if former is None else former
        if rec is not None and rec.get("command") != self.command:
            rec = None  # another command's record: its files are not ours
        if rec is not None and isinstance(rec.get("input_identity"), dict):  # earlier records keyed paths as typed
            rec = {**rec, "input_identity": {os.path.realpath(k): v for k, v in rec["input_identity"].items()}}
        changed = self._changed_since(rec, existing)
        if changed is not None and not self.overwrite:
            raise InvalidInputError(f"{changed} exists and was written since {self.command} made it with this record (by "
                                    "another command or by hand); pass --overwrite to replace it, or -o to write elsewhere")
        decision = decide_resume(planned, dict.fromkeys(planned, self.key), rec, identity, existing,
                                 record_exists=self.record.exists() or former is not None, overwrite=self.overwrite,
                                 maker=self.command, alias_keys=dict.fromkeys(planned, self._typed_key))
        if decision.action != "refuse":
            return
        first = next((p for p in self.paths if self._rel(p) in existing), self.record)
        if rec is None:
            more = len(existing) - 1 if first != self.record else len(existing)
            raise InvalidInputError(f"{first}{f' (and {more} more)' if more > 0 else ''} exists; pass --overwrite to "
                                    f"replace it (no record of {self.command} says it made it)")
        made_from = rec.get("input_identity") or {}
        if set(made_from) != set(identity):
            raise InvalidInputError(f"{first} exists and was made by {self.command} from other input files "
                                    f"({', '.join(sorted(made_from)) or 'none'}; this run reads "
                                    f"{', '.join(sorted(identity)) or 'none'}); pass --overwrite to replace it, or -o to "
                                    "write elsewhere")
        if not same_input(made_from, identity):
            changed = sorted(f for f in identity if not same_input(made_from.get(f), identity[f]))
            raise InvalidInputError(f"{first} exists and was made by {self.command} from {', '.join(changed)} as it was "
                                    "before it (or its sidecar) changed; pass --overwrite to replace it")
        raise InvalidInputError(f"{first} exists and was made by {self.command} with other settings; pass --overwrite to "
                                "replace it, or -o to write elsewhere")

    def _changed_since(self, rec: dict | None, existing: set) -> Path | None:
        """The first output that the record ``rec`` says this set made but that is no longer as
        the record found it (another command, or the user, wrote it since), or None. A record's
        claim is then stale: the file is not this set's to replace without ``--overwrite``."""
        made = (rec or {}).get("output_identity") or {}
        for p in self.paths:
            rel = self._rel(p)
            if rel in existing and rel in made and not as_recorded(made, rel, p):
                return p
        return None

    def _former_record(self) -> dict | None:
        """The record of this set under its former name (see ``formerly``), or None."""
        if self._former is None or self.record.exists():
            return None
        rec = read_record(self._former)
        if rec is None or set((rec.get("outputs") or {}).values()) != {self._rel(p) for p in self.paths}:
            return None
        return rec

    def _stale_outputs(self) -> list[Path]:
        """The files of the set this run replaces that it does not write again: those its record
        (of this command) lists, when the run was told to replace (``--overwrite``) and does
        replace that set (they share an output). Only a file as the record found it (its size and
        time unchanged: not one another command or the user wrote since), inside the set's folders,
        never an input of this run or one of its outputs."""
        rec = self._former_record() or read_record(self.record)
        if not self.overwrite or rec is None or rec.get("command") != self.command:
            return []
        new = {self._rel(p) for p in self.paths}
        listed = set((rec.get("outputs") or {}).values())
        made = rec.get("output_identity") or {}
        if not listed & new:
            return []  # another set under the same record's name: not this one's to clear
        keep = {os.path.realpath(p) for p in [*self.inputs, self.record]}
        out = []
        for rel in sorted(listed - new):
            rel_path = Path(str(rel))
            path = self._root / rel_path
            if rel_path.is_absolute() or ".." in rel_path.parts or os.path.realpath(path) in keep:
                continue
            if not path.is_file() or path.is_symlink() or any(_same_file(path, p) for p in self.paths):
                continue
            if as_recorded(made, rel, path):
                out.append(path)
        return out

    def _clear_stale_staging(self) -> None:
        """Staging folders of runs that were killed (their process is gone) are removed."""
        host = socket.gethostname()
        for d in self._root.glob(STAGING_PREFIX + "*") if self._root.is_dir() else ():
            parts = d.name[len(STAGING_PREFIX):].split("-")
            try:
                pid = int(parts[0])
                os.kill(pid, 0)
            except (ValueError, IndexError):
                continue
            except ProcessLookupError:
                if parts[1:2] == [host.replace("-", "")[:32]]:
                    shutil.rmtree(d, ignore_errors=True)
            except PermissionError:
                continue

    @contextlib.contextmanager
    def writing(self) -> Iterator[Callable[[str | Path], Path]]:
        """Stage the outputs: the block writes each output to ``stage(path)``; when it ends
        without error all of them are renamed into place at once and the record written. On an
        error or an interrupt the staged files are removed and the old outputs stay as they were.

        Yields
        ------
        stage : callable
            Path of an output -> the path to write it to (same name, in the staging folder).
        """
        self.check()  # again: the files may have appeared while the command worked
        # The folders this run makes for its outputs: removed again, if still empty, when it
        # writes nothing (an error, a stop).
        made = [d for d in (self._root, *self._root.parents) if not d.exists()]
        committed = False
        try:
            self._root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a place where no folder can be made (/proc, a read-only mount)
            raise type(exc)(exc.errno, f"cannot create the output folder ({exc.strerror})", str(self._root)) from None
        host = socket.gethostname().replace("-", "")[:32]
        try:
            staging = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-{host}-", dir=self._root))
        except OSError as exc:  # name the user's output, not the hidden folder beside it
            raise type(exc)(exc.errno, f"cannot write there ({exc.strerror})", str(self.paths[0])) from None
        staged = {p.absolute(): staging / self._rel(p) for p in self.paths}

        def stage(path) -> Path:
            target = staged.get(Path(path).absolute())
            if target is None:
                raise ValueError(f"{path} is not an output of this set")
            target.parent.mkdir(parents=True, exist_ok=True)
            return target

        try:
            try:
                yield stage
            except OSError as exc:  # name the user's file, not the staged one
                final = {str(v): str(k) for k, v in staged.items()}
                if exc.filename is not None and str(exc.filename) in final and exc.errno is not None:
                    raise type(exc)(exc.errno, exc.strerror, final[str(exc.filename)]) from None
                raise
            missing = [str(p) for p, s in staged.items() if not s.exists()]
            if missing:
                raise RuntimeError(f"outputs not written: {', '.join(missing)}")  # pragma: no cover - a bug
            with _folder_lock(self._root):
                self._commit(staged)
            committed = True
        finally:
            with held_signals():  # a stop that comes now waits for the staged files to be gone
                shutil.rmtree(staging, ignore_errors=True)
                for d in made if not committed else ():
                    with contextlib.suppress(OSError):  # not empty: something else is in it now
                        d.rmdir()

    def _commit(self, staged: dict) -> None:
        """Rename the staged outputs into place and write the record, after checking again what
        lies there now: another command may have written these outputs while this one worked
        (two runs into one folder), and those are replaced only as the first check allows."""
        self.check()
        former = self._former_record() is not None
        stale = self._stale_outputs()
        deliver_lost_stops()  # a Ctrl-C that came where it could not stop the command: nothing is written
        with held_signals():
            self._write_record("pending")
            for final, s in staged.items():
                final.parent.mkdir(parents=True, exist_ok=True)
                os.replace(s, final)
            for path in stale:
                path.unlink(missing_ok=True)
            self._write_record("done")
            if former:
                self._former.unlink(missing_ok=True)
        if stale:
            logging.getLogger("lfring.cli").info(
                "removed %d file%s of the set this run replaced, which it does not make again: %s", len(stale),
                "s" * (len(stale) > 1), ", ".join(str(p) for p in stale[:5]) + (", ..." if len(stale) > 5 else ""))

    def _write_record(self, status: str) -> None:
        from lfring import __version__

        rels = [self._rel(p) for p in self.paths]
        keys = dict.fromkeys(rels, self.key)
        atomic_write_text(self.record, json.dumps({
            RECORD_KEY: RECORD_VERSION, "command": self.command, "status": status, "input": self.inputs,
            "input_identity": {os.path.realpath(p): input_identity(p, digest=True) for p in self.inputs},
            "settings_key": self.key,
            "settings": self.settings, **({"made_with": self.made_with} if self.made_with else {}),
            "outputs": dict(zip(rels, rels)),
            "output_keys": keys if status == "done" else {}, "pending_keys": {} if status == "done" else keys,
            "output_identity": ({rel: file_identity(p, digest=True) for rel, p in zip(rels, self.paths)}
                                if status == "done" else {}),
            "lfring_version": __version__,
        }, indent=2, default=json_default) + "\n")
