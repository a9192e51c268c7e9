"""``lfring check``: is FRAME a ring frame for the calibration? Size, pattern, levels, exposure,
layout fit and view agreement, with an overlay of the layout on the frame."""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import FRAME, raw_options, read_calibrated_frame
from lfring.cli.outputs import OutputSet

log = logging.getLogger("lfring.cli.check")

_VERDICTS = {"": "ring frame", "flat_field": "a flat field of this camera, not a scene",
             "over_exposed": "NOT a frame to process"}


@click.command("check")
@click.argument("frame", type=FRAME)
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Overlay of the layout on the frame (.png). Default: FRAME's name with _check.png in the current folder.")
@click.option("--overwrite", is_flag=True, help="Replace an existing overlay.")
@raw_options
@click.pass_context
def command(ctx, frame, calib, output, overwrite, levels):
    """Check that FRAME is a ring frame for the calibration: lfring check raw.png

    Prints the frame's size, Bayer pattern and levels, its exposure (fractions of pixels
    clipped and dark inside the views' discs; a frame with a large clipped share is
    over-exposed, and refused past a larger one), how well the layout's discs fit its light, and
    how well the four views agree at the best of a few depths. Writes an overlay PNG of the
    layout on the frame. Exit code 0: a ring frame; 1: not one; 2: bad input.
    """
    from lfring.check import (CLIPPED_REFUSE, CLIPPED_WARN, DIM_LEVEL, FLAT_TEXTURE, PROCESS_ANYWAY, ExposureWarning, check_frame,
                              draw_layout)
    from lfring.io.demosaic import demosaic
    from lfring.io.writers import write_image

    out = Path(output) if output else Path(f"{Path(frame).stem}_check.png")
    if out.suffix.lower() != ".png":
        raise click.BadParameter(f"the overlay must end in .png, got {out.name!r}", param_hint="-o")
    outputs = OutputSet([out], name=out.name, overwrite=overwrite)
    outputs.check()
    raw, cal, cal_name = read_calibrated_frame(frame, calib, levels)
    image = demosaic(raw, method="bilinear")
    size = (image.shape[1], image.shape[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExposureWarning)  # said on the verdict line
        res = check_frame(image, cal, measure_fit=True)
    tried = list(res.agreement_by_depth)
    black = raw.black_level if not isinstance(raw.black_level, tuple) else ",".join(f"{b:g}" for b in raw.black_level)
    lines = [
        f"frame        {frame}: {size[0]} x {size[1]} px, "
        + (f"Bayer {raw.pattern}" if raw.pattern else "RGB") + f", {raw.bit_depth} bits",
        f"levels       black {black:g} white {raw.white_level:g} counts" if not isinstance(black, str)
        else f"levels       black {black} white {raw.white_level:g} counts",
        f"exposure     {res.clipped_fraction:.2%} clipped, {res.dark_fraction:.2%} dark (inside the views' discs; "
        f"over-exposed from {CLIPPED_WARN:.0%} clipped, refused from {CLIPPED_REFUSE:.0%}; under-exposed where their "
        f"brightest pixels, the 99th percentile, stay below {DIM_LEVEL:.0%} of the white level)",
        f"calibration  {cal_name} ({cal.raw_size[0]} x {cal.raw_size[1]} px, {cal.num_views} views)",
        f"layout fit   disc contrast {res.disc_contrast:.2f} (1: dark between the discs, 0: light everywhere)",
        f"agreement    {res.agreement:.2f} at {res.best_depth_m:.3g} m, the best of {len(tried)} depths tried from "
        f"{min(tried):.3g} to {max(tried):.3g} m (ring frames score above {res.threshold:g}; not a depth measurement)"
        if res.best_depth_m is not None else f"agreement    none measurable (threshold {res.threshold:g})",
        f"texture      {res.texture:.3f} of the mean inside the discs (a flat field's is below {FLAT_TEXTURE:g})"
        if np.isfinite(res.texture) else "texture      none measurable (no light inside the discs)",
        f"fit          views {res.fit_px:.3f} px from the calibration's homographies at {res.fit_depth_m:.4g} m "
        f"(median over tiles; lens distortion {'undone' if cal.distortion is not None else 'not modelled'}"
        f"{', flat field divided' if cal.flat_field is not None else ''})" if np.isfinite(res.fit_px)
        else "fit          not measured (not a ring frame to process)",
        # This is the check the user was sent to: what to do is to look, or to skip it.
        f"verdict      {_VERDICTS.get(res.reason, 'NOT a ring frame for this calibration')}"
        f"{(', ' + res.warning.split(':')[0]) if res.ok and res.warning else ''}: "
        f"{res.message.replace('; ' + PROCESS_ANYWAY, '; pass --no-check to the processing commands to use it anyway')}",
    ]
    with outputs.writing() as stage:
        write_image(stage(out), draw_layout(image, cal.layout))
    for line in lines:
        click.echo(line)
    click.echo(f"overlay      {out}" + (" (the frame turned 180 degrees, as the calibration cuts it)"
                                        if cal.layout.rotate180 else ""))
    if not res.ok:
        ctx.exit(1)
