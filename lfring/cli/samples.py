"""The sample frames committed in data/synthetic/, and how to make them again.

    python -m lfring.cli.samples data/synthetic

renders every sample with the ``lfring synth`` command recorded for it and writes
``manifest.json`` (command, seed and SHA-256 of every file). The samples are defined by those
commands, so they are made by running them. The flat frame is noise-free and the targets use
the 'low' noise preset, standing for the averages of many exposures that calibration captures
are; the scene and the parts use 'realistic' noise, the hard scene 'low' (with 'realistic'
noise its frame would take the folder past the size the sample set is kept under). The ``lens_``
samples (in ``lenses/``) are of the prototype with real mini-lenses (``calib/prototype_lenses.toml``),
a flat and two targets to calibrate its distortion from, on a 4 x 4 binned sensor at 8 bits
(small files).
"""

from __future__ import annotations

import hashlib
import json
import shlex
import sys
from pathlib import Path

from lfring.batch.record import RECORD_SUFFIX
from lfring.cli.main import main as cli

__all__ = ["SAMPLES", "SUBFOLDERS", "make_samples", "sha256"]

_COMMON = "--binning 2 --pattern RGGB --bit-depth 12"
_LENSES = "--device prototype_lenses --binning 4 --pattern RGGB --bit-depth 8"
#: name -> arguments of ``lfring synth`` (the output folder is appended).
SAMPLES = {
    "flat": f"flat {_COMMON} --noise none --seed 0",
    "target_0.3m": f"target --depth 0.3 {_COMMON} --noise low --seed 1",
    "target_0.5m": f"target --depth 0.5 {_COMMON} --noise low --seed 2",
    "target_1m": f"target --depth 1.0 {_COMMON} --noise low --seed 3",
    "scene": f"scene {_COMMON} --noise realistic --seed 4",
    "part_good": f"part --defects none {_COMMON} --noise realistic --seed 5",
    "part_defects": f"part --defects 0.015,-0.015 {_COMMON} --noise realistic --seed 6",
    # 'low' noise: with 'realistic' noise the frame would take data/synthetic past its size limit.
    "hard": f"hard {_COMMON} --noise low --seed 7",
    # Real mini-lenses (calib/prototype_lenses.toml: each its own distortion, up to 3 % of the disc
    # radius at the rim, and vignetting), calibrated from its own targets and flat. A 4 x 4 binned
    # sensor and 8 bits keep the three frames within the folder's size limit.
    "lens_flat": f"flat {_LENSES} --noise none --seed 0",
    "lens_target_0.3m": f"target --depth 0.3 {_LENSES} --noise low --seed 1",
    "lens_target_1m": f"target --depth 1.0 {_LENSES} --noise low --seed 3",
}

#: samples kept in a folder of their own: the real-lens frames are of another size than the
#: twin's (no built-in calibration fits them), so they stay out of the main folder's frames.
SUBFOLDERS = {"lens_flat": "lenses", "lens_target_0.3m": "lenses", "lens_target_1m": "lenses"}


def sha256(path: Path) -> str:
    """SHA-256 of a file's bytes, as recorded in data/synthetic/manifest.json.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def make_samples(outdir: str | Path, *, names=None, overwrite: bool = False) -> dict:
    """Render the samples into ``outdir`` and return the manifest (also written there when all
    samples are made)."""
    out = Path(outdir)
    entries = {}
    for name in names or SAMPLES:
        where = out / SUBFOLDERS.get(name, "")
        args = shlex.split(SAMPLES[name]) + ["--name", name, "-o", str(where)] + (["--overwrite"] if overwrite else [])
        code = cli(["-q", "synth", *args])
        if code != 0:
            raise RuntimeError(f"lfring synth {' '.join(args)} failed with exit code {code}")
        # The command's record (which names this run's inputs and version) is not a sample.
        (where / f"{name}{RECORD_SUFFIX}").unlink(missing_ok=True)
        files = sorted(p for p in where.glob(f"{name}*") if p.is_file()) + sorted((where / f"{name}_truth").iterdir())
        entries[name] = {
            "command": "lfring synth " + SAMPLES[name] + f" --name {name} -o "
                       + "/".join(["data/synthetic", *([SUBFOLDERS[name]] if name in SUBFOLDERS else [])]),
            "seed": int(shlex.split(SAMPLES[name])[-1]),
            "files": {p.relative_to(out).as_posix(): sha256(p) for p in files},
        }
    if names is None:
        from lfring import __version__

        manifest = {
            "description": "Frames of the synthetic twin: prototype optics, 2 x 2 binned sensor (2456 x 1842 px, 2.5 um), "
                           "12-bit RGGB; lens_*: the prototype with real mini-lenses (device prototype_lenses: each "
                           "lens's distortion and vignetting), 4 x 4 binned (1228 x 920 px), 8-bit RGGB. Each NAME.png "
                           "has a sidecar NAME.png.json (pattern, levels) and a NAME_truth/ folder (per-view depth in "
                           "metres, layout.json, truth.json with the exact homographies and each view's distortion).",
            "regenerate": "python -m lfring.cli.samples data/synthetic --overwrite",
            "lfring_version": __version__,
            "samples": entries,
        }
        (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return entries


if __name__ == "__main__":  # pragma: no cover
    argv = sys.argv[1:]
    make_samples(argv[0] if argv else "data/synthetic", overwrite="--overwrite" in argv)
