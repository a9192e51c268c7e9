"""``lfring split``: cut a raw frame into its sub-aperture views."""

from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import FRAME, output_folder, raw_options, read_frame
from lfring.cli.outputs import OutputSet
from lfring.errors import LfringError

log = logging.getLogger("lfring.cli.split")

_METHODS = ("bilinear", "edge-aware", "vng", "rawpy", "kornia")


@click.command("split")
@click.argument("raw", type=FRAME)
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, callback=output_folder, metavar="DIR",
              help="Output folder (created if missing).")
@click.option("--layout", "layout_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Layout JSON (from a previous split, or a twin's truth folder).")
@click.option("--flat", "flat_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Flat (white) frame to detect the layout from.")
@click.option("--rotate180", is_flag=True, help="The camera outputs the frame rotated by 180 degrees (with --flat or detection).")
@click.option("--method", type=click.Choice(_METHODS), default="edge-aware", show_default=True, help="Demosaicing method.")
@click.option("--format", "fmt", type=click.Choice(["png", "tiff"]), default="png", show_default=True,
              help="View files: 16-bit PNG or 16-bit TIFF.")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@raw_options
def command(raw, outdir, layout_file, flat_file, rotate180, method, fmt, overwrite, levels):
    """Cut RAW into its views: DIR/<name>_view<k>.png (k = 0 top-left, 1 top-right, 2
    bottom-left, 3 bottom-right), the layout DIR/<name>_layout.json and a sidecar
    DIR/<name>_views.json.

    The layout comes from --layout, else is detected on --flat, else on RAW itself (less
    precise: the scene's content near the view edges biases it).
    """
    from lfring.calibration.defaults import calibration_for_frame
    from lfring.io.demosaic import demosaic
    from lfring.io.writers import write_image, write_json
    from lfring.views import Layout, detect_layout, split_views

    if layout_file and flat_file:
        raise click.UsageError("give --layout or --flat, not both")
    if layout_file and rotate180:
        raise click.UsageError("--rotate180 goes with --flat or detection; a layout file records its own rotation")
    # Its Bayer pattern and levels, where the frame lacks them, from the built-in calibration for
    # its size, as every command takes them (the layout is detected, not the calibration's).
    try:
        builtin = calibration_for_frame(raw)
    except LfringError:  # no built-in calibration has the frame's size: any camera's frame splits
        builtin = None
    frame = read_frame(raw, levels, builtin[0] if builtin else None, picked=True)
    image = demosaic(frame, method=method)
    if layout_file:
        layout, source = Layout.load(layout_file), f"layout file {layout_file}"
    elif flat_file:
        flat = demosaic(read_frame(flat_file, levels, builtin[0] if builtin else None, picked=True), method="bilinear")
        if flat.shape != image.shape:
            raise click.UsageError(f"--flat {flat_file} is {flat.shape[1]} x {flat.shape[0]} px but the frame {raw} is "
                                   f"{image.shape[1]} x {image.shape[0]} px; give a flat frame of the same camera and binning")
        layout = detect_layout(flat, kind="flat", rotate180=rotate180, name=f"--flat {flat_file}")
        source = f"detected on flat {flat_file}"
    else:
        layout, source = detect_layout(image, rotate180=rotate180, name=raw), "detected on the frame itself"
        log.warning("no --layout or --flat: layout detected on the frame itself, which is less precise")
    views = split_views(image, layout)
    out = Path(outdir)
    stem = Path(raw).stem
    ext = "png" if fmt == "png" else "tiff"
    paths = [out / f"{stem}_view{k}.{ext}" for k in range(layout.num_views)]
    layout_path, side_path = out / f"{stem}_layout.json", out / f"{stem}_views.json"
    outputs = OutputSet([*paths, layout_path, side_path], name=f"{stem}_views", overwrite=overwrite)
    outputs.check()
    with outputs.writing() as stage:
        def write(k: int) -> None:
            v = views[k] if views.shape[-1] == 3 else views[k, ..., 0]
            write_image(stage(paths[k]), np.rint(np.clip(v, 0.0, 1.0) * 65535.0).astype(np.uint16))

        # Encoding dominates; the encoders release the GIL, so the views are written in parallel.
        with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
            list(pool.map(write, range(layout.num_views)))
        layout.save(stage(layout_path))
        write_json(stage(side_path), {
            "input": str(raw),
            "layout_source": source,
            "layout_file": layout_path.name,
            "views": [p.name for p in paths],
            "view_order": "0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right",
            "values": "linear, (counts - black) / (white - black) scaled to 0..65535",
            "pattern": frame.pattern,
            "black_level": frame.black_level,
            "white_level": frame.white_level,
            "demosaic": method if frame.pattern else None,  # an RGB frame is not demosaiced
        })
    log.info("%s: %d views of %d x %d px (%s) -> %s", raw, layout.num_views, layout.view_shape[1], layout.view_shape[0], source, out)

