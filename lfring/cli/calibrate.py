"""``lfring calibrate``: refocusing calibration from frames of a planar target at known depths."""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import check_calibration_output, get_device, raw_options
from lfring.cli.outputs import OutputSet
from lfring.errors import InvalidInputError

log = logging.getLogger("lfring.cli.calibrate")
WARN_PX = 0.3
"""Residual (px) above which a calibration gets a warning: check the target, focus and depths."""
MAX_RESIDUAL_PX = 0.5
"""Residual (px) above which a calibration is refused unless --force: the views of a planar
target at its depth align to a small fraction of a pixel (the twin's to about 0.01 px); a frame
that is not one (a scene with depth, a part) leaves residuals of a pixel or more."""


def _floaty(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


@click.command("calibrate")
@click.argument("frames", nargs=-1, required=True)
@click.option("--depths", required=True, metavar="Z1 Z2 ...",
              help="Target distance of each frame from the main lens [m], in the order of the frames "
                   "(space- or comma-separated).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), metavar="FILE", help="Calibration JSON to write.")
@click.option("--flat", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Flat (white) frame: layout detection and flat-fielding.")
@click.option("--layout", "layout_file", type=click.Path(dir_okay=False), default=None, metavar="FILE", help="Layout JSON to use.")
@click.option("--rotate180", is_flag=True,
              help="The camera writes its frames rotated by 180 degrees (with --flat or detection; a --layout records its "
                   "own rotation): the calibration turns every frame split with it upright.")
@click.option("--depth-origin", default="auto", show_default=True, metavar="auto|optics|M",
              help="z0 of H(Z) = A + B/(Z - z0) [m]: 'auto' fits it with 3+ planes and with 2 takes the --device's "
                   "entrance pupil s (0 without --device); 'optics' always takes s; or a number.")
@click.option("--device", "device_name", default=None, metavar="NAME|FILE",
              help="Device description (e.g. prototype), for z0 from the optics.")
@click.option("--method", type=click.Choice(["ecc", "sift"]), default="ecc", show_default=True,
              help="Per-plane homographies: direct alignment (ECC) or SIFT + RANSAC.")
@click.option("--rank1", is_flag=True, help="Constrain each B_k to rank 1.")
@click.option("--no-distortion", "no_distortion", is_flag=True,
              help="Do not estimate the mini-lenses' distortion (use the views as they are cut).")
@click.option("--carry-flat", "carry_flat", is_flag=True,
              help="Keep the --flat frame's field (each view's vignetting) in the calibration: views split with it "
                   "are flat-fielded.")
@click.option("--force", is_flag=True, help=f"Write the calibration even when a residual exceeds {MAX_RESIDUAL_PX} px "
              "(frames that do not look like a planar target at their depth).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@raw_options(calibration=False)
def command(frames, depths, output, flat, layout_file, rotate180, depth_origin, device_name, method, rank1, no_distortion,
            carry_flat, force, overwrite, levels):
    """Calibrate refocusing in metric depth from FRAMES of a textured planar target.

    Example: lfring calibrate near.png far.png --depths 0.3 1.0 --flat white.png -o calib/mycam.json

    Estimates each view's lens distortion with the homographies and keeps it when it matters;
    prints the views' misregistration before and after undoing it, and the residual of every
    view and plane in pixels, warns above 0.3 px and refuses above 0.5 px (a frame that is not
    a planar target at its depth) unless --force. Refuses
    depths whose order contradicts the ring (views of nearer planes lie farther apart), the same
    frame given for two depths, and a plane that the --device's optics (or the built-in
    calibration for the frames' size) put too far to tell from infinity, as lfring inspect does:
    most often millimetres given as metres. With --device, warns of a plane whose views the
    optics put at a depth well away from the one given (a distance measured from the wrong
    point, or given for another frame). The calibration records the device and the frames' Bayer pattern and levels: later commands
    read frames without a sidecar with them.
    """
    from lfring.calibration import calibrate
    from lfring.calibration.fit import camera_model
    from lfring.calibration.model import check_depth_origin
    from lfring.views import Layout

    frames = list(frames)
    extra = []
    while frames and _floaty(frames[-1]) and not Path(frames[-1]).exists():
        extra.insert(0, frames.pop())
    tokens = [t for t in re.split(r"[,\s]+", depths.strip()) if t] + extra
    missing = [f for f in frames if not Path(f).exists()]
    if missing:
        # click reads `--depths 0.3 abc` as one depth and a third frame: say so.
        trailing = missing == frames[len(frames) - len(missing):]
        if trailing and len(frames) - len(missing) == len(tokens) + len(missing):
            raise click.BadParameter(f"expected a number of metres for each frame, got {' '.join(tokens + missing)!r}",
                                     param_hint="--depths")
        raise click.BadParameter(f"no such file: {', '.join(missing)}", param_hint="FRAMES")
    try:
        zs = [float(t) for t in tokens]
    except ValueError:
        raise click.BadParameter(f"expected a number of metres for each frame, got {' '.join(tokens)!r}",
                                 param_hint="--depths") from None
    if len(zs) != len(frames):
        raise click.UsageError(f"{len(frames)} frame(s) but {len(zs)} depth(s): give one depth per frame")
    if len(frames) < 2:
        raise click.UsageError("calibration needs frames at two or more depths")
    if any(not math.isfinite(z) or z <= 0 for z in zs):
        raise click.BadParameter(f"expected a positive number of metres for each frame, got {' '.join(tokens)}",
                                 param_hint="--depths")
    if len(set(zs)) != len(zs):
        raise click.BadParameter(f"each frame needs its own depth (the depths must be distinct), got {' '.join(tokens)}",
                                 param_hint="--depths")
    check_calibration_output(output)
    if flat and layout_file:
        raise click.UsageError("give --flat or --layout, not both")
    if layout_file and rotate180:
        raise click.UsageError("--rotate180 goes with --flat or detection; a layout file records its own rotation")
    if carry_flat and not flat:
        raise click.UsageError("--carry-flat needs --flat FILE")
    device = get_device(device_name) if device_name else None
    if depth_origin == "auto":
        z0 = None
    elif depth_origin == "optics":
        if device is None:
            raise click.UsageError("--depth-origin optics needs --device NAME|FILE")
        z0 = device.entrance_pupil_m
    else:
        try:
            z0 = float(depth_origin)
        except ValueError:
            raise click.BadParameter(f"expected auto, optics or metres, got {depth_origin!r}", param_hint="--depth-origin") from None
    if z0 is not None:
        check_depth_origin(z0, min(zs), name="--depth-origin")
    outputs = OutputSet([output], name=Path(output).name, overwrite=overwrite)
    outputs.check()
    layout = Layout.load(layout_file) if layout_file else None
    cal = calibrate(dict(zip(zs, frames)), flat=flat, layout=layout, depth_origin_m=z0, method=method, rank1=rank1,
                    device=device, distortion=not no_distortion, carry_flat=carry_flat, rotate180=rotate180,
                    **levels.as_kwargs())
    ref, ref_name = camera_model(cal, device)
    if device is None and z0 is None and len(zs) == 2 and ref is not None and getattr(ref, "device", None):
        # z0 was assumed 0: a built-in calibration of these frames knows a device that would give it.
        log.warning("%s names the device '%s': if these frames are that camera's, --device %s gives z0 from its "
                    "optics instead of 0", ref_name, ref.device, ref.device)
    _refuse_too_far(cal, dict(zip(zs, frames)), ref, ref_name)
    _warn_far(dict(zip(zs, frames)), ref)
    click.echo(f"z0 = {cal.depth_origin_m:.6f} m ({cal.provenance.get('depth_origin')}); valid depth range "
               f"{cal.valid_depth_range_m[0]:g} to {cal.valid_depth_range_m[1]:g} m; reference view {cal.model.reference}")
    if len(zs) == 3 and cal.provenance.get("depth_origin") == "fitted":
        click.echo("leave-one-out not measured: z0 fitted to three planes fits any three depths, so no plane can check "
                   "the others (a fourth plane can, or --depth-origin optics with --device)")
    click.echo(f"{'plane [m]':>10} " + " ".join(f"{'view ' + str(k) + ' px':>10}" for k in range(cal.num_views))
               + (f" {'leave-one-out px':>17}" if cal.planes and cal.planes[0].leave_one_out_px is not None else ""))
    worst, worst_z = 0.0, None
    for p, diag in zip(cal.planes, cal.provenance["planes"]):
        line = f"{p.depth_m:10.4g} " + " ".join(f"{r:10.3f}" for r in p.residual_px)
        if p.leave_one_out_px is not None:
            line += f" {np.max(p.leave_one_out_px):17.3f}"
        click.echo(line)
        if "alignment_residual_before_px" in diag:
            click.echo(f"{'before':>10} " + " ".join(f"{r:10.3f}" for r in diag["alignment_residual_before_px"]))
        click.echo(f"{'alignment':>10} " + " ".join(f"{r:10.3f}" for r in diag["alignment_residual_px"]))
        plane_worst = max(float(np.max(p.residual_px)), float(np.max(diag["alignment_residual_px"])),
                          float(np.max(p.leave_one_out_px)) if p.leave_one_out_px is not None else 0.0)
        if plane_worst > worst:
            worst, worst_z = plane_worst, p.depth_m
    if worst > MAX_RESIDUAL_PX and not force:
        frame = dict(zip(zs, frames)).get(worst_z, "a frame")
        raise InvalidInputError(
            f"largest residual {worst:.3f} px (plane {worst_z:g} m, {frame}) exceeds {MAX_RESIDUAL_PX} px: it does not look "
            "like a planar target at that depth (check the frame, the target's texture, focus and the depths); "
            f"{output} is not written; pass --force to write it anyway")
    _echo_distortion(cal)  # a verdict on a calibration that is kept: not before a refusal of it
    if worst > WARN_PX:
        log.warning("largest residual %.3f px exceeds %.1f px: check the target's texture, focus and the depths%s", worst,
                    WARN_PX, ", or leave out --no-distortion: the lenses may distort the views" if no_distortion else "")
    with outputs.writing() as stage:
        cal.save(stage(output))
    log.info("wrote %s", output)


def _tells_from_infinity(calibration, depth_m: float) -> bool:
    """Whether ``calibration`` tells a plane at ``depth_m`` from infinity, by the rule ``lfring
    inspect`` applies to its --plane (:func:`lfring.inspect.default_depth_band` at zero
    tolerance: the search around the depth must not reach infinity)."""
    from lfring.inspect import default_depth_band

    try:
        default_depth_band(calibration, depth_m, depth_m, 0.0)
    except InvalidInputError:
        return False
    return True


def _refuse_too_far(cal, frames_by_depth: dict, ref, what: str) -> None:
    """Refuse depths that contradict the camera: most often millimetres given as metres.

    The calibration fitted to the frames cannot tell on its own (its scale comes from the given
    depths). A model of the camera that does not rest on them (``ref``, in words ``what``:
    :func:`lfring.calibration.fit.camera_model`) can: when
    it puts even the nearest plane too far to tell from infinity while the frames show that
    plane's views moving as a near plane's do, the depths are wrong. A plane that both put too
    far is a camera too coarse for it, not a unit mistake, and is left to the residuals.
    """
    near = min(frames_by_depth)
    if ref is None or near <= ref.valid_depth_range_m[0]:
        return
    if _tells_from_infinity(ref, near) or not _tells_from_infinity(cal, near):
        return
    raise InvalidInputError(
        f"by {what}, the nearest plane, given as {near:g} m ({frames_by_depth[near]}), lies too far to tell from "
        "infinity (lfring inspect refuses such a --plane alike), yet the frames show its views moving as a near "
        "plane's do: --depths are in metres, not mm"
    )


def _warn_far(frames_by_depth: dict, ref) -> None:
    """Warn of a farthest plane that the camera model ``ref`` (:func:`lfring.calibration.fit.camera_model`) puts beyond its
    range and, read as millimetres, within it (:meth:`RingCalibration.millimetres_hint`). Two
    planes fit exactly whatever their depths, and a distant scene is a valid plane at infinity,
    so it is not refused."""
    far = max(frames_by_depth)
    if ref is not None and far / 1000.0 > min(frames_by_depth) and ref.millimetres_hint(far):
        log.warning("the farthest plane is given as %g m (%s): fine for a target that far; if %g was millimetres, "
                    "give %g", far, frames_by_depth[far], far, far / 1000.0)


def _echo_distortion(cal) -> None:
    """One line on the lens distortion: modelled or not, and the views' misregistration (RMS over
    the target's tiles) with homographies alone and with the distortion undone."""
    info = cal.provenance.get("distortion") or {}
    if not info.get("estimated"):
        click.echo("distortion not estimated" + (f" ({info['reason']})" if info.get("reason") else ""))
        return
    before, after = info["tiles_rms_before_px"], info["tiles_rms_after_px"]
    if info.get("modelled"):
        click.echo(f"distortion modelled: views misregistered by {before:.3f} px RMS with homographies alone, {after:.3f} px "
                   f"with each view's distortion undone (it moves the views' maps by up to {info['effect_px']:.3f} px); "
                   "the 'alignment' rows are measured on the undistorted views, 'before' on the views as cut")
    else:
        click.echo(f"distortion negligible, not modelled: it would move the views' maps by at most {info['effect_px']:.3f} px "
                   f"(misregistration {before:.3f} px RMS, {after:.3f} px with it)")
