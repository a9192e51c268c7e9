"""``lfring inspect``: check a part against the working plane; exit 0 pass, 1 defects, 2 error, 3 cannot judge."""

from __future__ import annotations

import dataclasses

import logging
from pathlib import Path

import click

from lfring.cli._options import FRAME, check_option, flat_option, load_views, output_folder, raw_options
from lfring.cli.outputs import OutputSet
from lfring.cli.words import cli_words
from lfring.inspect import MIN_COVERAGE
from lfring.inspect.records import BEYOND_SIGHT_TOLD

log = logging.getLogger("lfring.cli.inspect")

#: Exit code of a frame that cannot be judged (0 pass, 1 defects, 2 bad input or a failed step).
EXIT_CANNOT_JUDGE = 3


def _parse_roi(ctx, param, text):
    if text is None:
        return None
    parts = text.split(",")
    try:
        vals = tuple(int(p) for p in parts)
    except ValueError:
        raise click.BadParameter(f"expected X,Y,W,H as four integers in pixels, got {text!r}") from None
    if len(vals) != 4:
        raise click.BadParameter(f"expected X,Y,W,H (four integers in pixels), got {text!r}")
    return vals


def _read_depth(path: str):
    """A float32 depth map in metres from a TIFF or PFM file."""
    import numpy as np
    import tifffile

    from lfring.depth.io import read_pfm
    from lfring.errors import FileFormatError, LfringFileNotFoundError

    p = Path(path)
    if not p.is_file():
        raise LfringFileNotFoundError(f"reference depth file not found: {p}")
    suffix = p.suffix.lower()
    if suffix == ".pfm":
        arr = read_pfm(p)
    elif suffix in (".tif", ".tiff"):
        try:
            arr = tifffile.imread(p)
        except (tifffile.TiffFileError, ValueError) as exc:
            raise FileFormatError(f"{p}: not a readable TIFF ({exc})") from None
    else:
        raise FileFormatError(f"reference depth must be a .tiff/.tif or .pfm file in metres, got {p.name!r}")
    if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.floating):
        raise FileFormatError(f"{p}: expected a single-channel float depth map in metres, got {arr.dtype} {arr.shape}")
    return arr.astype(np.float32)


@click.command("inspect")
@click.argument("raw", type=FRAME)
@click.option("--plane", type=float, required=True, metavar="M", help="Working plane [m from the main lens].")
@click.option("--tolerance", type=float, required=True, metavar="M", help="Largest accepted deviation [m], e.g. 0.01.")
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, callback=output_folder, metavar="DIR", help="Output folder.")
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("--roi", callback=_parse_roi, default=None, metavar="X,Y,W,H",
              help="Region of interest in pixels of the reference frame (default: the whole frame).")
@click.option("--reference-depth", "reference_depth", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Expected depth per pixel (float32 TIFF or PFM, metres, the reference frame) instead of the plane.")
@click.option("--min-area", type=int, default=150, show_default=True, metavar="PX", help="Smallest defect [px].")
@click.option("--min-confidence", type=float, default=0.6, show_default=True,
              help="Less confident pixels (untextured, occluded) never raise an alarm and count as unchecked.")
@click.option("--min-coverage", type=float, default=MIN_COVERAGE, show_default=True, metavar="FRACTION",
              help="Smallest fraction of the part checked with confident depth for a pass, in [0, 1]; below it the "
                   "exit code is 3.")
@click.option("--zmin", type=float, default=None, metavar="M", help="Nearest depth searched [m] (default: a band around the plane, as far as the tolerance needs).")
@click.option("--zmax", type=float, default=None, metavar="M", help="Farthest depth searched [m] (default: the band's far end).")
@click.option("--reference", default="center", show_default=True, metavar="center|0..3", help="Frame of the maps and boxes.")
@click.option("--backend", type=click.Choice(["numpy", "torch"]), default="numpy", show_default=True, help="Plane-sweep backend.")
@click.option("--device-file", "device_name", default=None, metavar="NAME|FILE",
              help="Device description for areas in mm^2 (default: the calibration's, else prototype).")
@click.option("--viewer", is_flag=True, help="Also write DIR/<name>_viewer.html: the interactive viewer with the defect "
              "boxes and the unchecked area as overlays (see lfring view).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@raw_options
@check_option
@flat_option
@click.pass_context
def command(ctx, raw, plane, tolerance, outdir, calib, roi, reference_depth, min_area, min_confidence, min_coverage, zmin,
            zmax, reference, backend, device_name, viewer, overwrite, levels, no_check, flat):
    """Check that the part in RAW lies on the working plane within the tolerance.

    Writes DIR/<name>_inspect.png (refocused at the plane, the plane tinted green, defect boxes:
    bumps red, dents blue, the part's unchecked pixels hatched) and DIR/<name>_inspect.json
    (verdict, coverage, the reason when the part cannot be judged, settings, each defect's box
    in reference-frame pixels, area in px and mm^2, maximum deviation in mm: + towards the
    camera, - away). Exit code 0: pass; 1: defects found; 2: bad input or a failed step
    (nothing written); 3: cannot judge (frame too dark or too flat, not a ring frame for the
    calibration (unless --no-check), no surface at the plane, or
    less than --min-coverage of the part checked; the report is written).
    """
    from lfring.check import check_frame
    from lfring.errors import LfringError
    from lfring.core.geometry import check_reference
    from lfring.inspect import annotate, inspect_frame, report
    from lfring.io.writers import write_image, write_json
    from lfring.depth.io import device_for
    from lfring.optics.device import load_device

    # A frame that is not a ring frame for the calibration cannot be judged (exit 3 with the
    # check's reason), rather than refused as bad input: the line needs a verdict for every part.
    views, cal, cal_name = load_views(raw, calib, levels, check=False, flat=flat)
    frame_check = None if no_check else check_frame(views, cal)
    ref = check_reference(reference, cal.num_views)
    out = Path(outdir)
    stem = Path(raw).stem
    png, js = out / f"{stem}_inspect.png", out / f"{stem}_inspect.json"
    html = out / f"{stem}_viewer.html"
    outputs = OutputSet([png, js, *([html] if viewer else [])], name=f"{stem}_inspect", overwrite=overwrite)
    outputs.check()
    target = _read_depth(reference_depth) if reference_depth else None
    # The optics give areas in mm^2: --device-file's (a name or file that does not load is an
    # error), else the calibration's, else the prototype, binned to the frames (device_for);
    # without a match areas are left in pixels.
    named = load_device(device_name) if device_name else None
    dev = None
    try:
        dev = device_for(cal, named)
    except LfringError as exc:
        log.warning("defect areas in px only: %s", exc)  # the log speaks the options' words (device= as --device-file)
    res = inspect_frame(views, cal, plane_m=plane, tolerance_m=tolerance, roi=roi, reference_depth_m=target,
                        reference=ref, min_area_px=min_area, min_confidence=min_confidence,
                        min_coverage=min_coverage, zmin_m=zmin, zmax_m=zmax,
                        device=dev, backend=backend)
    if frame_check is not None and not frame_check.ok and res.verdict != "cannot_judge":
        res = dataclasses.replace(res, verdict="cannot_judge", defects=(),
                                  reason=f"not a ring frame for this calibration: {frame_check.message}")
    with outputs.writing() as stage:
        write_image(stage(png), annotate(res))
        write_json(stage(js), report(res, raw=str(raw), calibration=cal_name, reference_depth=reference_depth,
                                     annotated_image=str(png)))
        if viewer:
            import warnings

            from lfring.errors import LfringWarning
            from lfring.viewer import inspection_overlays, write_viewer

            with warnings.catch_warnings():  # the band's range was warned about by the inspection
                warnings.simplefilter("ignore", LfringWarning)
                write_viewer(stage(html), views, cal, reference=ref, min_confidence=min_confidence, overwrite=True,
                             title=Path(raw).name, metadata={"input": str(raw), "calibration": cal_name, "plane_m": plane,
                                                             "tolerance_m": tolerance}, **inspection_overlays(res))
    for i, d in enumerate(res.defects, 1):
        x, y, w, h = d.bbox_px
        log.info("defect %d: %s %s%+.1f mm at x=%d y=%d (%d x %d px), %d px, confidence %.2f%s", i, d.kind,
                 "at least " if d.beyond_band else "", d.deviation_m * 1e3, x, y, w, h, d.area_px, d.mean_confidence,
                 " (it reaches beyond the depth band searched: widen --zmin/--zmax to measure it)" if d.beyond_band else "")
    checked = f"checked {res.coverage:.0%} of the part"
    beyond = res.stats.get("beyond_sight_fraction") or 0.0
    if res.verdict != "cannot_judge" and beyond >= BEYOND_SIGHT_TOLD:
        checked += f"; it may run on beyond what two views see, over {beyond:.0%} more, unchecked"
    if res.verdict == "pass":
        verdict = f"pass ({checked})"
    elif res.verdict == "fail":
        verdict = f"fail ({len(res.defects)} defect{'s' if len(res.defects) != 1 else ''}, {checked})"
    else:
        verdict = f"cannot judge ({cli_words(res.reason)})"
    log.info("%s: %s at %.3f m +- %.1f mm", raw, verdict, plane, tolerance * 1e3)
    click.echo(f"{js}: {verdict}")
    if res.verdict == "fail":
        ctx.exit(1)
    if res.verdict == "cannot_judge":
        ctx.exit(EXIT_CANNOT_JUDGE)
