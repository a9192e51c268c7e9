"""``lfring refocus``: refocus a raw frame at metric depth, or build a focal stack."""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import (
    FRAME,
    REFOCUS_KERNELS,
    SWEEP_METAVAR,
    aperture_options,
    check_option,
    depth_range_words,
    flat_option,
    load_views,
    note_first_compile,
    parse_depths,
    parse_range,
    progress_bar,
    raw_options,
)
from lfring.cli.outputs import OutputSet
from lfring.core.warping import DEFAULT_INTERPOLATION

log = logging.getLogger("lfring.cli.refocus")


def json_depth(z: float):
    """A depth as the outputs' JSON gives it: metres, or "inf" (JSON has no infinity) for
    infinity and for the depth that stands for it in rendering."""
    from lfring.calibration.overlap import INFINITE_DEPTH_M

    return z if z < INFINITE_DEPTH_M else "inf"


def encode(image: np.ndarray, bit_depth: int, encoding: str) -> np.ndarray:
    """Linear [0, 1] float -> uint8/uint16, sRGB-encoded or linear (see lfring.io.writers.encode_image)."""
    from lfring.io.writers import encode_image

    return encode_image(image, bit_depth, encoding)


def caption(frame: np.ndarray, text: str) -> np.ndarray:
    """An 8-bit frame with ``text`` drawn in its top-left corner (white on a dark box)."""
    import cv2

    out = np.ascontiguousarray(frame).copy()
    scale = max(0.4, out.shape[0] / 600)
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    pad = max(2, th // 3)
    out[: th + base + 2 * pad, : tw + 2 * pad] //= 3
    white = (255,) * (out.shape[2] if out.ndim == 3 else 1)
    cv2.putText(out, text, (pad, th + pad), cv2.FONT_HERSHEY_SIMPLEX, scale, white, 1, cv2.LINE_AA)
    return out


def _depths(depth, depths, sweep) -> list[float]:
    given = [x is not None for x in (depth, depths, sweep)]
    if sum(given) != 1:
        raise click.UsageError(f"give exactly one of --depth Z, --depths Z1,Z2,... or --sweep {SWEEP_METAVAR}")
    if depth is not None:
        zs, hint = [depth], "--depth"
    elif depths is not None:
        zs, hint = list(parse_depths(depths, param_hint="--depths")), "--depths"
    else:
        start, stop, n = parse_range(sweep, with_count=True, param_hint="--sweep", metavar=SWEEP_METAVAR)
        if not (math.isfinite(start) and math.isfinite(stop)):  # no even steps reach infinity
            raise click.BadParameter(f"a sweep runs between two finite depths, got {sweep!r}; give infinity with "
                                     "--depths Z1,...,inf", param_hint="--sweep")
        # Rounded to 12 significant digits: the depths as written (0.45, not 0.44999999999999996).
        zs, hint = [float(f"{z:.12g}") for z in np.linspace(start, stop, n)], "--sweep"
    for z in zs:
        if not (z > 0 and not math.isnan(z)):
            raise click.BadParameter(f"depths must be positive metres (or inf), got {z!r}", param_hint=hint)
    twice = sorted({z for z in zs if zs.count(z) > 1})
    if twice:
        raise click.BadParameter(f"{', '.join(f'{z:g} m' for z in twice)} would be made more than once: give each depth "
                                 "once", param_hint=hint)
    return [float(z) for z in zs]


@click.command("refocus")
@click.argument("raw", nargs=-1, required=True, type=FRAME)
@click.option("--depth", type=float, default=None, metavar="M", help="Refocus distance from the main lens [m]; inf for infinity.")
@click.option("--depths", default=None, metavar="Z1,Z2,...", help="Several depths [m]: a focal stack.")
@click.option("--sweep", default=None, metavar=SWEEP_METAVAR, help="N depths from START to STOP [m]: a focal stack.")
@click.option("--all-in-focus", "aif", is_flag=True,
              help="Also write an all-in-focus image: every pixel at its depth in the depth map (--method depth-aware), "
                   "else at the depth of the stack's (or the calibrated range's) where the views agree best.")
@click.option("--calib", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Calibration JSON (default: the built-in one for the frame's size).")
@click.option("--reference", default="center", show_default=True, metavar="center|INDEX", help="Frame of the result.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Output image (.png/.tif); for stacks the numbered frames and the stack files take its name. "
                   "Default: RAW's name with _refocus_<depth>m (a stack: _stack) in the current folder.")
@click.option("--interpolation", type=click.Choice(["cubic", "linear"]), default=DEFAULT_INTERPOLATION, show_default=True,
              help="Resampling of the views: bicubic keeps more detail, bilinear is faster.")
@click.option("--method", type=click.Choice(["depth-aware", "shift-and-add"]), default="depth-aware", show_default=True,
              help="depth-aware: what the lens's whole aperture would record (smooth, occlusion-correct blur from a "
                   "depth map estimated over --zmin..--zmax; out of focus measured closer to it than shift-and-add on a "
                   "real light field and on the twin, the same in focus, much slower per depth); shift-and-add: the "
                   "views' average (out-of-focus objects as four copies).")
@aperture_options
@click.option("--zmin", type=float, default=None, metavar="M", help="depth-aware: nearest depth of the depth estimation [m] "
              "(default: the calibration's valid range).")
@click.option("--zmax", type=float, default=None, metavar="M", help="depth-aware: farthest depth of the depth estimation [m] "
              "(default: the calibration's valid range; without an upper bound, where the views stop moving when the "
              "range up to there is one of depths, as for a calibration from the optics; else required).")
@click.option("--bit-depth", type=click.Choice(["8", "16"]), default="8", show_default=True, help="Bits per sample.")
@click.option("--encoding", type=click.Choice(["srgb", "linear"]), default="srgb", show_default=True,
              help="Write display-ready sRGB values, or linear light.")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@raw_options
@check_option
@flat_option
def command(raw, depth, depths, sweep, aif, calib, reference, output, interpolation, method, aperture, f_number, zmin, zmax,
            bit_depth, encoding, overwrite, levels, no_check, flat):
    """Refocus RAW at metric depth: lfring refocus raw.png --depth 0.5

    RAW is one raw frame, or several images: separate views in the view order of --calib (a
    stereo pair or a grid of views; lfring grid-calib writes such a calibration).

    By default (--method depth-aware) a depth map is estimated and every out-of-focus pixel is
    blurred by its own circle of confusion, as a lens of --aperture (or --f-number) would;
    --method shift-and-add averages the views instead. A focal stack (--depths or --sweep) is
    written as numbered images, a multi-page TIFF (depths in its metadata) and an animated GIF
    (each frame captioned with its depth); the depth map is estimated once for the stack.
    Every image gets a JSON sidecar (IMAGE.json) naming the calibration used; its depth_m is
    in metres, or the string "inf" for --depth inf (JSON has no infinity); a stack's TIFF keeps
    its depths, encoding, bit depth and method in its metadata instead. The outputs' record
    (NAME.lfring.json beside them) says what made them, so a rerun knows them. Depths nearer
    than where the views overlap are refused (the error names the nearest that works); frames
    that are not ring frames for the calibration are refused unless --no-check.
    """
    import warnings

    from lfring.batch.settings import depth_label
    from lfring.calibration.overlap import INFINITE_DEPTH_M, check_renderable
    from lfring.errors import LfringWarning
    from lfring.core.geometry import check_reference
    from lfring.io.writers import write_gif, write_image, write_json, write_tiff_stack
    from lfring.focus import Refocuser, all_in_focus, focal_stack, resolve_aperture
    from lfring.depth.estimate import estimate_depth
    from lfring.focus.depth_aware import check_aperture_options, depth_of_field, estimation_range

    zs = _depths(depth, depths, sweep)
    bits = int(bit_depth)
    stem, raw = Path(raw[0]).stem, raw[0] if len(raw) == 1 else list(raw)  # several: separate view images
    mark = "_stack" if len(zs) > 1 else ""  # a stack's files and record carry it in their names
    if output is None:
        # The method is in the default name: its images differ, and neither replaces the other's.
        how = "" if method == "depth-aware" else f"_{method}"
        base = Path(f"{stem}_refocus_{depth_label(zs[0])}m{how}.png" if len(zs) == 1 else f"{stem}{mark}{how}.png")
        mark = ""  # already in the name
    else:
        base = Path(output)
    if output is not None and (str(output).endswith(("/", os.sep)) or base.is_dir()):
        raise click.BadParameter(f"-o names the image file to write (.png, .tif or .tiff), got the folder {output!r}; "
                                 f"e.g. -o {base / f'{stem}_refocus.png'}", param_hint="-o")
    if base.suffix.lower() not in (".png", ".tif", ".tiff"):
        raise click.BadParameter(f"output must end in .png, .tif or .tiff, got {str(output or base)!r}", param_hint="-o")
    if len(zs) == 1:
        outs = [base]
    else:
        outs = [base.with_name(f"{base.stem}_{i:03d}_{depth_label(z)}m{base.suffix}") for i, z in enumerate(zs)]
    extra = []
    if len(zs) > 1:
        extra = [base.with_name(base.stem + mark + ".tif"), base.with_name(base.stem + mark + ".gif")]
    aif_path = base.with_name(base.stem + "_all_in_focus" + base.suffix) if aif else None
    sidecars = [Path(str(p) + ".json") for p in outs + ([aif_path] if aif else [])]
    all_outputs = [*outs, *extra, *sidecars, *([aif_path] if aif else [])]
    # The record is named after the output's whole name: a.png and a.tif are two sets.
    set_stem = base.stem + mark
    outputs = OutputSet(all_outputs, name=set_stem + base.suffix, formerly=set_stem, overwrite=overwrite)
    # The options' own checks first: a refusal for an existing file, then for the option, made
    # the user pass --overwrite to learn the option was wrong.
    if method != "depth-aware" and any(v is not None for v in (aperture, f_number, zmin, zmax)):
        raise click.UsageError("--aperture, --f-number, --zmin and --zmax are for --method depth-aware")
    if method == "depth-aware":
        check_aperture_options(aperture, f_number)
    outputs.check()
    views, cal, cal_name = load_views(raw, calib, levels, check=not no_check, flat=flat)
    ref = check_reference(reference, cal.num_views)
    dof = {}
    if method == "depth-aware":
        # The depth estimation's range, by the rule every entry point follows (refused here,
        # before the long work, when the calibration gives none); the sidecar records it.
        zmin, zmax = estimation_range(cal, zmin, zmax, reference=ref)
        cal.check_depth([zmin, zmax])  # warned here, as lfring depth does: the block below silences it
        dof = {"aperture": aperture, "f_number": f_number, "zmin_m": zmin, "zmax_m": zmax}
        note_first_compile(REFOCUS_KERNELS)
    check_renderable(cal, zs, reference=ref)
    outputs.check()  # again: loading took a while

    # inf renders as the model's limit H = A (see INFINITE_DEPTH_M).
    render_zs = [INFINITE_DEPTH_M if math.isinf(z) else z for z in zs]
    # Validates and warns once for the whole stack (inf by name: the model is extrapolated there).
    cal.check_depth([z for z in zs if math.isfinite(z)] or [cal.valid_depth_range_m[0]])
    if any(math.isinf(z) for z in zs) and cal.valid_depth_range_m[1] is not None:
        warnings.warn(f"depth inf is outside the calibrated range ({cal.valid_depth_range_m[0]:g} to "
                      f"{cal.valid_depth_range_m[1]:g} m); the model is extrapolated", LfringWarning, stacklevel=2)
    meta = {"input": raw, "calibration": cal_name, "calibration_source": cal.source, "reference": ref,
            "encoding": encoding, "bit_depth": bits, "interpolation": interpolation, "method": method,
            "units": "depth in metres from the main lens"}
    meta.update({k: v for k, v in dof.items() if v is not None})
    # Which aperture made the images: depth-aware's, resolved from --f-number when given;
    # shift-and-add has none (its copies sit on the rim of the aperture the views span).
    meta["aperture"] = resolve_aperture(cal, aperture, f_number) if method == "depth-aware" else None
    if f_number is not None:
        meta["f_number_device"] = cal.device  # whose main lens and view positions turned it into the aperture
    outputs.made_with = {"method": method, "aperture": meta["aperture"]}
    stack = []
    narrow = depth_range_words("widen the range, or use --method shift-and-add (it needs no depth map)")
    with outputs.writing() as stage, narrow, warnings.catch_warnings(), progress_bar(len(zs), "refocus", "depth") as bar:
        warnings.simplefilter("ignore", LfringWarning)
        renderer = None
        if method == "depth-aware":  # one depth map, one renderer of it: the stack and the all-in-focus image
            depth_map = estimate_depth(views, cal, zmin_m=zmin, zmax_m=zmax, reference=ref)
            renderer = depth_of_field(views, cal, depth=depth_map, reference=ref)
            images = focal_stack(views, cal, render_zs, reference=ref, interpolation=interpolation, method=method,
                                 depth=renderer, aperture=aperture, f_number=f_number)
        else:
            images = (Refocuser(cal, zr, reference=ref, view_shape=views.shape[1:3], interpolation=interpolation)(views)
                      for zr in render_zs)
        for p, z, img in zip(outs, zs, images):
            write_image(stage(p), encode(img, bits, encoding))
            write_json(stage(str(p) + ".json"), {**meta, "depth_m": json_depth(z)})
            log.info("made %s (%s m)", p, depth_label(z))
            if len(zs) > 1:
                stack.append(img)
            bar.update(1)
        if len(zs) > 1:
            write_tiff_stack(stage(extra[0]), np.stack([encode(s, bits, encoding) for s in stack]),
                             metadata={"depths_m": [json_depth(z) for z in zs], "encoding": encoding,
                                       "bit_depth": bits, "method": method})
            labels = [f"{z:.4g} m" if math.isfinite(z) else "inf" for z in zs]
            write_gif(stage(extra[1]), np.stack([caption(encode(s, 8, "srgb"), t) for s, t in zip(stack, labels)]),
                      frame_ms=250)
        if aif:
            if renderer is not None:  # each pixel at its depth in the map, as the stack renders it
                img, chosen = all_in_focus(views, cal, depth_map_m=renderer, reference=ref)
                chosen_over = "depth map"
            else:  # each pixel at the depth where the views agree best
                img, chosen = all_in_focus(views, cal, render_zs if len(zs) > 1 else None, reference=ref)
                chosen_over = [json_depth(z) for z in zs] if len(zs) > 1 else "calibrated range"
            write_image(stage(aif_path), encode(img, bits, encoding))
            # The all-in-focus image is the depth-aware renderer's at aperture 0, whatever --method.
            write_json(stage(str(aif_path) + ".json"), {
                **meta, "method": "depth-aware", "aperture": 0.0, "all_in_focus_depths_m": chosen_over,
                "chosen_depth_range_m": [json_depth(float(np.nanmin(chosen))), json_depth(float(np.nanmax(chosen)))]})
    log.info("wrote %s", ", ".join(map(str, all_outputs)) if len(all_outputs) <= 4 else
             f"{len(all_outputs)} files in {base.parent}")
    for p in outs:
        click.echo(str(p))
