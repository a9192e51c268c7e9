"""``lfring grid-calib``: the calibration of a rectified stereo pair or a regular grid of views."""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import click

from lfring.views import MAX_VIEWS

log = logging.getLogger("lfring.cli.grid_calib")


#: How grid-calib's messages name the grid's disparity model (the library names its parameters).
_DISPARITY_OPTIONS = ("--disparity-scale", "--disparity-offset", "--depth-origin")


def _pair(text: str, sep: str, what: str, hint: str) -> tuple[float, float]:
    parts = [p for p in re.split(sep, text.strip()) if p]
    try:
        a, b = (float(p) for p in parts)
    except ValueError:
        raise click.BadParameter(f"expected {what}, got {text!r}", param_hint=hint) from None
    return a, b


def _size(text: str, hint: str, form: str) -> tuple[int, int]:
    w, h = _pair(text, r"[xX,]", f"{form} (two positive integers)", hint)
    if not (math.isfinite(w) and math.isfinite(h) and w == int(w) >= 1 and h == int(h) >= 1):
        raise click.BadParameter(f"expected {form} (two positive integers), got {text!r}", param_hint=hint)
    return int(w), int(h)


def _positions(grid: str | None, positions: str | None) -> list[tuple[float, float]]:
    if grid is not None and positions is not None:
        raise click.UsageError("give --grid COLSxROWS or --positions 'X,Y X,Y ...', not both")
    if positions is not None:
        what = "X,Y grid positions separated by spaces"
        if not positions.split():
            raise click.BadParameter(f"expected {what}, got {positions!r}", param_hint="--positions")
        return [_pair(p, r",", what, "--positions") for p in positions.split()]
    cols, rows = _size(grid or "2x1", "--grid", "COLSxROWS")
    if cols * rows > MAX_VIEWS:
        raise click.BadParameter(f"a grid of {cols} x {rows} has {cols * rows} views: at most {MAX_VIEWS}", param_hint="--grid")
    return [(float(k % cols), float(k // cols)) for k in range(cols * rows)]


@click.command("grid-calib")
@click.option("--size", required=True, metavar="WxH", help="Size of every view [px].")
@click.option("--grid", default=None, metavar="COLSxROWS",
              help="Views on a regular grid, numbered row by row from the top left (default 2x1: a rectified stereo "
                   "pair, left view first).")
@click.option("--positions", default=None, metavar="'X,Y X,Y ...'",
              help="Each view's position on the grid in grid units (x right, y down), in view order, instead of --grid.")
@click.option("--disparity-scale", type=float, required=True, metavar="PX_M",
              help="B of the disparity per grid step d(Z) = OFFSET + B / (Z - Z0) [px m] (focal length [px] x "
                   "baseline [m] for a stereo pair).")
@click.option("--disparity-offset", type=float, default=0.0, show_default=True, metavar="PX",
              help="Disparity per grid step at infinite depth [px].")
@click.option("--depth-origin", type=float, default=0.0, show_default=True, metavar="M",
              help="Z0: depth of the plane of the projection centres [m].")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), metavar="FILE", help="Calibration JSON to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def command(size, grid, positions, disparity_scale, disparity_offset, depth_origin, output, overwrite):
    """Write the calibration of views on a regular grid, from its geometry.

    A point at depth Z lies d(Z) pixels further left in the view one grid step to the right
    (and further up one step down): for a Middlebury pair, imL(x, y) = imR(x - d, y). Use the
    calibration with the separate view images, in its view order:

        lfring grid-calib --size 450x375 --disparity-scale 100 -o pair.json

        lfring depth left.png right.png --calib pair.json --zmin 2 --zmax 50 --reference 0 -o out/
    """
    from lfring.calibration import RingCalibration
    from lfring.calibration.build import check_grid_disparity
    from lfring.cli._options import check_calibration_output
    from lfring.cli.outputs import OutputSet

    w, h = _size(size, "--size", "WxH")
    pos = _positions(grid, positions)
    check_grid_disparity(disparity_scale, disparity_offset, depth_origin, names=_DISPARITY_OPTIONS)
    check_calibration_output(output)
    cal = RingCalibration.from_grid((h, w), pos, disparity_scale_px_m=disparity_scale, disparity_offset_px=disparity_offset,
                                    depth_origin_m=depth_origin)
    outputs = OutputSet([output], name=Path(output).name, overwrite=overwrite)
    outputs.check()
    with outputs.writing() as stage:
        cal.save(stage(output))
    lo, _ = cal.valid_depth_range_m
    log.info("%d views of %d x %d px; valid beyond %.4g m", cal.num_views, w, h, lo)
    click.echo(str(output))
