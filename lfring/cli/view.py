"""``lfring view``: one self-contained HTML viewer of a raw frame (click to refocus, depth in mm)."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from lfring.cli._options import (FRAME, REFOCUS_KERNELS, aperture_options, check_option, depth_range_words, load_views,
                                 note_first_compile, raw_options)
from lfring.cli.outputs import OutputSet

log = logging.getLogger("lfring.cli.view")


@click.command("view")
@click.argument("raw", type=FRAME)
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("--zmin", type=float, default=None, metavar="M", help="Nearest depth [m] (default: the calibration's range).")
@click.option("--zmax", type=float, default=None, metavar="M", help="Farthest depth [m] (default: the calibration's range; without an upper bound, "
              "as lfring refocus derives it, where the calibration allows).")
@click.option("--planes", type=int, default=None, metavar="N",
              help="Depth hypotheses, one stack frame each (default: one pixel of view motion apart).")
@click.option("--reference", default="center", show_default=True, metavar="center|0..3", help="Frame of the viewer.")
@click.option("--min-confidence", type=float, default=0.5, show_default=True,
              help="Below this the depth is shaded as unreliable and skipped when a click picks the focus.")
@click.option("--method", type=click.Choice(["depth-aware", "shift-and-add"]), default="depth-aware", show_default=True,
              help="Refocusing of the focal stack, as lfring refocus --method: depth-aware renders what the lens's whole "
                   "aperture would record from the page's depth map; shift-and-add averages the views (out-of-focus "
                   "objects as four copies).")
@aperture_options
@click.option("--format", "image_format", type=click.Choice(["jpeg", "webp"]), default="jpeg", show_default=True,
              help="Encoding of the focal stack's frames.")
@click.option("--quality", type=click.IntRange(1, 100), default=85, show_default=True, help="Encoder quality.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Output .html (default: RAW's name with _viewer.html in the current folder).")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
@raw_options
@check_option
def command(raw, calib, zmin, zmax, planes, reference, min_confidence, method, aperture, f_number, image_format, quality,
            output, overwrite, levels, no_check):
    """Write an interactive viewer of RAW: lfring view frame.png -o viewer.html

    One HTML file with everything inline (no network, no server): a focal stack over the depth
    range, the all-in-focus image, the depth map and its confidence. Click a point to refocus at
    its depth; the cursor reads the depth in mm; arrow keys step the focus. Frames that are not
    ring frames for the calibration are refused unless --no-check.
    """
    from lfring.core.geometry import check_reference
    from lfring.focus import resolve_aperture
    from lfring.viewer import write_viewer

    out = Path(output) if output is not None else Path(f"{Path(raw).stem}_viewer.html")
    if out.suffix.lower() not in (".html", ".htm"):
        raise click.BadParameter(f"output must end in .html, got {out.name!r}", param_hint="-o")
    if method != "depth-aware" and (aperture is not None or f_number is not None):
        raise click.UsageError("--aperture and --f-number are for --method depth-aware")
    outputs = OutputSet([out], name=out.name, overwrite=overwrite)
    outputs.check()
    views, cal, cal_name = load_views(raw, calib, levels, check=not no_check)
    ref = check_reference(reference, cal.num_views)
    outputs.made_with = {"method": method,
                         "aperture": resolve_aperture(cal, aperture, f_number) if method == "depth-aware" else None}
    note_first_compile(REFOCUS_KERNELS)
    with outputs.writing() as stage, depth_range_words(
            lambda n: "widen the range" if n is None else f"give --planes {n} or more, or widen the range"):
        write_viewer(stage(out), views, cal, zmin_m=zmin, zmax_m=zmax, num_planes=planes, reference=ref,
                     min_confidence=min_confidence, image_format=image_format, quality=quality, overwrite=True,
                     title=Path(raw).name, metadata={"input": str(raw), "calibration": cal_name}, method=method,
                     aperture=aperture, f_number=f_number)
    log.info("wrote %s (%.1f MB)", out, out.stat().st_size / 1e6)
    click.echo(str(out))
