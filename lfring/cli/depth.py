"""``lfring depth``: metric depth map with confidence from a raw frame, by plane sweep."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from lfring.depth.costs import COSTS
from lfring.depth.plan import DEPTH_TAPER
from lfring.cli._options import check_option, flat_option, load_views, progress_bar, raw_options

log = logging.getLogger("lfring.cli.depth")


@click.command("depth")
@click.argument("raw", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--zmin", type=float, required=True, metavar="M", help="Nearest depth searched [m from the main lens].")
@click.option("--zmax", type=float, required=True, metavar="M", help="Farthest depth searched [m].")
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, metavar="DIR", help="Output folder.")
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("--planes", type=int, default=None, metavar="N",
              help="Number of depth hypotheses (default: at most 1 px of view motion apart).")
@click.option("--reference", default="center", show_default=True, metavar="center|INDEX", help="Frame of the depth map.")
@click.option("--cost", type=click.Choice(list(COSTS)), default=None,
              help="Photo-consistency cost (default: lcn-halves for --method sgm, lcn for local). lcn: locally "
                   "normalised luminances, the fastest; lcn-halves (sgm only): the same, and where no depth suits "
                   "all views, the views on one side of the reference if they agree (next to depth edges); "
                   "lcn-occlusion: the same, leaving out a view hidden behind an occluder where that is cheaper.")
@click.option("--aggregation", type=click.Choice(["box", "guided"]), default="box", show_default=True,
              help="Spatial aggregation of the cost (guided: edge-aware, slower, measured more accurate on the twin).")
@click.option("--method", type=click.Choice(["sgm", "local"]), default="sgm", show_default=True,
              help="sgm: semi-global optimisation of the whole sweep (fills weak texture, rejects occlusions); "
                   "local: each pixel's best hypothesis alone (several times faster).")
@click.option("--paths", "scan_paths", type=click.Choice(["4", "8"]), default="4", show_default=True,
              help="Scan paths of --method sgm (8 adds the diagonals: about twice the optimisation's time).")
@click.option("--consistency/--no-consistency", default=None,
              help="--method sgm: estimate again from the farthest view and make unknown the pixels whose two answers "
                   "disagree (the left-right check; doubles the time). Default: on for two views, off for more.")
@click.option("--threads", type=click.IntRange(min=1), default=None, metavar="N",
              help="Threads of the sweep and the optimisation (default: OpenCV's thread count).")
@click.option("--rim-taper", type=float, default=DEPTH_TAPER, show_default=True, metavar="FRACTION",
              help="Share of each view's disc radius over which its weight rises from 0 (a smaller share measures "
                   "more of the dark periphery; inspection uses 0.15).")
@click.option("--backend", type=click.Choice(["numpy", "torch"]), default="numpy", show_default=True, help="Compute backend.")
@click.option("--device", default=None, metavar="cpu|cuda", help="Torch device (default: cuda when present).")
@click.option("--min-confidence", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="Pixels below this confidence are black in the preview and left out of the point cloud.")
@click.option("--device-file", "device_name", default=None, metavar="NAME|FILE",
              help="Device description for the point cloud (default: the calibration's, else prototype).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@raw_options
@check_option
@flat_option
def command(raw, zmin, zmax, outdir, calib, planes, reference, cost, aggregation, method, scan_paths, consistency, threads,
            rim_taper, backend, device, min_confidence, device_name, overwrite, levels, no_check, flat):
    """Depth map of RAW in metres with confidence, by plane sweep over the views.

    RAW is one raw frame, or several images: separate views in the view order of --calib (a
    stereo pair or a grid of views; lfring grid-calib writes such a calibration).

    Writes DIR/<name>_depth.tiff (float32 metres, NaN where unknown), _depth.pfm,
    _confidence.tiff (0..1), _depth_preview.png (colour bar in metres), _points.ply (metric
    camera coordinates) and _depth.json (settings, hypotheses, calibration used); with the
    default --method sgm also _depth_filled.tiff (the unknown pixels filled from their image
    region: an estimate, not a measurement).
    """
    from lfring.depth import estimate_depth
    from lfring.depth.io import depth_to_points, write_depth_preview, write_depth_tiff, write_pfm, write_ply
    from lfring.core.geometry import check_reference
    from lfring.io.writers import check_writable, write_float_tiff, write_json
    from lfring.optics.device import load_device

    out = Path(outdir)
    stem, raw = Path(raw[0]).stem, raw[0] if len(raw) == 1 else list(raw)  # several: separate view images
    names = ["depth.tiff", "depth.pfm", "confidence.tiff", "depth_preview.png", "points.ply", "depth.json"]
    if method == "sgm":
        names.append("depth_filled.tiff")
    paths = {k: out / f"{stem}_{k}" for k in names}
    check_writable(paths.values(), overwrite=overwrite)
    views, cal, cal_name = load_views(raw, calib, levels, check=not no_check, flat=flat)
    ref = check_reference(reference, cal.num_views)
    with progress_bar(100, "depth", "%") as bar:
        res = estimate_depth(views, cal, zmin_m=zmin, zmax_m=zmax, num_planes=planes, reference=ref, cost=cost,
                             aggregation=aggregation, method=method, rim_taper=rim_taper, backend=backend, device=device,
                             threads=threads, paths=int(scan_paths), consistency=consistency,
                             progress=lambda f: bar.update(max(0, round(100 * f) - bar.n)))
    out.mkdir(parents=True, exist_ok=True)
    write_depth_tiff(paths["depth.tiff"], res.depth_m)
    if res.depth_filled_m is not None:
        write_depth_tiff(paths["depth_filled.tiff"], res.depth_filled_m)
    write_pfm(paths["depth.pfm"], res.depth_m)
    write_float_tiff(paths["confidence.tiff"], res.confidence)
    write_depth_preview(paths["depth_preview.png"], res.depth_m, confidence=res.confidence, zmin_m=zmin, zmax_m=zmax,
                        title=f"{stem}: depth (m)", min_confidence=min_confidence)
    # The point cloud needs the optics: the calibration's device, else the prototype, binned to
    # the frame's size when that matches.
    n_points = 0
    if not (device_name or cal.device):
        log.info("the calibration names no device and no --device-file was given: the point cloud uses the prototype's optics")
    dev = load_device(device_name or cal.device or "prototype")
    scale = dev.sensor_width_px // cal.raw_size[0]
    dev = dev.binned(scale) if scale > 1 else dev
    if (dev.sensor_width_px, dev.sensor_height_px) == cal.raw_size:
        rgb = views.mean(axis=0) if ref == "center" else views[ref]
        pts, cols = depth_to_points(res.depth_m, dev, cal.layout, ref, colors=np.clip(rgb, 0, 1), confidence=res.confidence,
                                    min_confidence=min_confidence)
        write_ply(paths["points.ply"], pts, cols)
        n_points = len(pts)
    else:
        log.warning("no device description matches %d x %d px frames: the point cloud is not written", *cal.raw_size)
    write_json(paths["depth.json"], {
        "input": raw, "calibration": cal_name, "reference": ref, "zmin_m": zmin, "zmax_m": zmax,
        "hypotheses_m": res.depths_m, "step_px": res.step_px, "cost": res.cost, "aggregation": aggregation, "method": method,
        "paths": res.paths, "consistency": res.consistency, "rim_taper": rim_taper, "backend": backend,
        "units": "depth in metres from the main lens; NaN where unknown", "points": n_points,
        "confidence_median": float(np.median(res.confidence)),
    })
    log.info("%s: %d hypotheses %.2f px apart; depth %.3f-%.3f m; %d points", raw, len(res.depths_m), res.step_px,
             float(np.nanmin(res.depth_m)), float(np.nanmax(res.depth_m)), n_points)
    click.echo(str(paths["depth.tiff"]))
