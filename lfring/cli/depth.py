"""``lfring depth``: metric depth map with confidence from a raw frame, by plane sweep."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from lfring.depth.costs import COSTS
from lfring.depth.plan import DEPTH_TAPER
from lfring.cli._options import FRAME, check_option, flat_option, load_views, note_first_compile, output_folder, progress_bar, raw_options
from lfring.cli.outputs import OutputSet

log = logging.getLogger("lfring.cli.depth")

MANY_PLANES = 300
"""Depth hypotheses above which ``lfring depth`` warns that the sweep takes long (a range whose
near end is a typo, say) and names the calibration's range and --planes."""

MAX_PLANES = 1000
"""Depth hypotheses above which ``lfring depth`` refuses unless --planes says how many."""


@click.command("depth")
@click.argument("raw", nargs=-1, required=True, type=FRAME)
@click.option("--zmin", type=float, default=None, metavar="M",
              help="Nearest depth searched [m from the main lens] (default: the calibration's valid range).")
@click.option("--zmax", type=float, default=None, metavar="M", help="Farthest depth searched [m] (default: the calibration's "
              "valid range; for one open to infinity, where the views stop moving).")
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, callback=output_folder, metavar="DIR", help="Output folder.")
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("--planes", type=int, default=None, metavar="N",
              help=f"Number of depth hypotheses (default: at most 1 px of view motion apart; above {MAX_PLANES} "
                   "planes the default is refused, a range that asks for so many is likely a typo).")
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
                   "local: each pixel's best hypothesis alone (faster on small frames, not on large views over many "
                   "planes).")
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
@click.option("--torch-device", "torch_device", default=None, metavar="cpu|cuda",
              help="With --backend torch: the torch device (default: cuda when present).")
@click.option("--device", "old_torch_device", default=None, hidden=True, metavar="cpu|cuda",
              help="Former name of --torch-device.")
@click.option("--min-confidence", type=click.FloatRange(0.0, 1.0), default=0.5, show_default=True,
              help="Pixels below this confidence are black in the preview and left out of the point cloud.")
@click.option("--device-file", "device_name", default=None, metavar="NAME|FILE",
              help="Device description (optics) for the point cloud (default: the calibration's, else prototype).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@raw_options
@check_option
@flat_option
def command(raw, zmin, zmax, outdir, calib, planes, reference, cost, aggregation, method, scan_paths, consistency, threads,
            rim_taper, backend, torch_device, old_torch_device, min_confidence, device_name, overwrite, levels, no_check, flat):
    """Depth map of RAW in metres with confidence, by plane sweep over the views.

    RAW is one raw frame, or several images: separate views in the view order of --calib (a
    stereo pair or a grid of views; lfring grid-calib writes such a calibration).

    Writes DIR/<name>_depth.tiff (float32 metres; NaN where too few views see a pixel, and for
    a pair where the left-right check fails: how far each depth can be trusted is the
    confidence's to say), _depth.pfm, _confidence.tiff (0..1), _depth_preview.png (colour bar in
    metres; pixels under --min-confidence black), _points.ply (metric camera coordinates, the
    pixels at --min-confidence or more, sRGB colours) and _depth.json (settings, hypotheses,
    calibration used, and the pinhole that turns the map into the points: points_camera); with the default --method sgm also _depth_filled.tiff (the unconfident
    pixels filled from confident ones of their image region: an estimate, not a measurement;
    NaN where too few views see a pixel). The files appear together, or none of them.
    """
    from lfring.core.geometry import check_reference
    from lfring.depth import estimate_depth
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.depth.io import device_for, points_camera, write_depth_preview, write_depth_tiff, write_pfm, write_ply
    from lfring.core.validate import check_number
    from lfring.errors import InvalidInputError, LfringError
    from lfring.focus.depth_aware import estimation_range
    from lfring.io.writers import write_float_tiff, write_json

    if old_torch_device is not None:
        if torch_device is not None:
            raise click.UsageError("give --torch-device (--device is its former name), not both")
        log.warning("--device is now --torch-device in lfring depth (in lfring calibrate --device names the optics)")
        torch_device = old_torch_device
    if torch_device is not None and backend != "torch":
        raise click.UsageError(f"--torch-device {torch_device} goes with --backend torch (the numpy backend runs on the CPU)")
    out = Path(outdir)
    given = " ".join(raw)  # the inputs as the log names them
    stem, raw = Path(raw[0]).stem, raw[0] if len(raw) == 1 else list(raw)  # several: separate view images
    names = ["depth.tiff", "depth.pfm", "confidence.tiff", "depth_preview.png", "depth.json"]
    if method == "sgm":
        names.append("depth_filled.tiff")
    paths = {k: out / f"{stem}_{k}" for k in names}
    OutputSet([*paths.values(), out / f"{stem}_points.ply"], name=f"{stem}_depth", overwrite=overwrite).check()
    views, cal, cal_name = load_views(raw, calib, levels, check=not no_check, flat=flat)
    ref = check_reference(reference, cal.num_views)
    lo, hi = cal.valid_depth_range_m
    check_number(zmin, "--zmin", above=0.0, allow_none=True, what="a distance in metres")  # before the bound's words below
    if zmax is not None:
        zmin, zmax = estimation_range(cal, zmin, zmax, reference=ref)
    else:
        # The range of depth-aware refocusing, by its one rule: a calibration open to infinity
        # ends where the views stop moving, when that is a range of depths at all.
        try:
            zmin, zmax = estimation_range(cal, zmin, reference=ref)
        except InvalidInputError:
            raise click.UsageError(f"the calibration {cal_name} has no upper depth bound, and none follows from it: "
                                   "give --zmax (metres)") from None
    if planes is None:
        n = len(depth_hypotheses(cal, zmin, zmax))
        span = f"--zmin {zmin:g} to --zmax {zmax:g} m"
        valid = f"the calibration's valid range is {lo:g} to {hi:g} m" if hi is not None else f"the calibration starts at {lo:g} m"
        if n > MAX_PLANES:
            raise click.UsageError(f"{span} asks for {n} depth planes (1 px of view motion apart), more than {MAX_PLANES}: "
                                   f"is a bound a typo? ({valid}); narrow the range, or give --planes N to sweep N planes")
        if n > MANY_PLANES:
            log.warning("%s asks for %d depth planes (1 px of view motion apart): this takes long (%s; --planes N "
                        "sweeps fewer)", span, n, valid)
    # The point cloud needs the optics: --device-file, else the calibration's device, else the
    # prototype, binned to the frame's size when that matches.
    try:
        dev = device_for(cal, device_name)
    except LfringError as exc:
        if device_name:
            raise
        dev = None
        log.warning("%s: the point cloud is not written (--device-file names the camera's optics)", exc)
    if dev is not None:
        if not (device_name or cal.device):
            log.warning("the calibration names no device and no --device-file was given: the point cloud's X and Y use "
                        "the prototype's optics, which may not be this camera's (--device-file names the camera's)")
        paths["points.ply"] = out / f"{stem}_points.ply"
    outputs = OutputSet(paths.values(), name=f"{stem}_depth", overwrite=overwrite)
    note_first_compile()
    with progress_bar(100, "depth", "%") as bar:
        res = estimate_depth(views, cal, zmin_m=zmin, zmax_m=zmax, num_planes=planes, reference=ref, cost=cost,
                             aggregation=aggregation, method=method, rim_taper=rim_taper, backend=backend,
                             device=torch_device, threads=threads, paths=int(scan_paths), consistency=consistency,
                             progress=lambda f: bar.update(max(0, round(100 * f) - bar.n)))
    n_points = 0
    with outputs.writing() as stage:
        write_depth_tiff(stage(paths["depth.tiff"]), res.depth_m)
        if res.depth_filled_m is not None:
            write_depth_tiff(stage(paths["depth_filled.tiff"]), res.depth_filled_m)
        write_pfm(stage(paths["depth.pfm"]), res.depth_m)
        write_float_tiff(stage(paths["confidence.tiff"]), res.confidence,
                         metadata={"quantity": "depth confidence", "range": [0, 1], "no depth": 0})
        write_depth_preview(stage(paths["depth_preview.png"]), res.depth_m, confidence=res.confidence, zmin_m=zmin,
                            zmax_m=zmax, title=f"{stem}: depth (m)", min_confidence=min_confidence)
        if dev is not None:
            rgb = views.mean(axis=0) if ref == "center" else views[ref]
            pts, cols = res.to_points(cal, colors=np.clip(rgb, 0, 1), min_confidence=min_confidence, device=dev)
            write_ply(stage(paths["points.ply"]), pts, cols)
            n_points = len(pts)
            if not n_points:
                log.warning("no pixel has a depth at --min-confidence %g or more: the point cloud is empty", min_confidence)
        known = np.isfinite(res.depth_m)
        write_json(stage(paths["depth.json"]), {
            "input": raw, "calibration": cal_name, "reference": ref, "zmin_m": zmin, "zmax_m": zmax,
            "hypotheses_m": res.depths_m, "step_px": res.step_px, "cost": res.cost, "aggregation": aggregation,
            "method": method, "paths": res.paths, "consistency": res.consistency, "rim_taper": rim_taper,
            "backend": backend, "units": "depth in metres from the main lens; NaN where unknown", "points": n_points,
            "min_confidence": min_confidence,
            # How the point cloud's points come from the map (None: no point cloud, no device).
            "points_camera": None if dev is None else points_camera(dev, cal.layout, ref),
            # Over the pixels with a depth: those no view pair sees have confidence 0 and no depth.
            "confidence_median": float(np.median(res.confidence[known])) if known.any() else None,
        })
    log.info("%s: %d hypotheses %.2f px apart; depth %.3f-%.3f m; %d points", given, len(res.depths_m), res.step_px,
             float(np.nanmin(res.depth_m)), float(np.nanmax(res.depth_m)), n_points)
    click.echo(str(paths["depth.tiff"]))
