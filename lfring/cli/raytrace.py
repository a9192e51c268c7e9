"""``lfring raytrace``: the 2D ray-trace figure of the ring camera (paper Fig. 4)."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import check_figure_output, device_option, get_device
from lfring.cli.outputs import OutputSet
from lfring.errors import DeviceError, InvalidInputError
from lfring.io.atomic import atomic_write_text
from lfring.optics.positions import METHODS, design, evaluate
from lfring.optics.raytrace import APERTURES, LOWER, MISSED_RING, STOPPED_MAIN, UPPER, bundle_stats, trace

log = logging.getLogger(__name__)

_COUNT_OPTIONS = {"num_points": "--points", "rays_per_point": "--rays", "rays_per_lens": "--rays-per-lens"}
"""The ray counts as :func:`lfring.optics.raytrace.trace` names them, and the options that set
them: its messages (which hold the counts' bounds) reach the user in the options' words."""
_COUNT_NAMES = re.compile(r"\b(" + "|".join(_COUNT_OPTIONS) + r")\b(=)?")


def _option_words(message: str) -> str:
    """``message`` of :func:`~lfring.optics.raytrace.trace` with its count names as options
    (``rays_per_lens=0`` as ``--rays-per-lens 0``)."""
    return _COUNT_NAMES.sub(lambda m: _COUNT_OPTIONS[m[1]] + (" " if m[2] else ""), message)


@click.command("raytrace")
@click.option("--object-size", "object_size_m", type=float, required=True, metavar="M",
              help="Object size 2*h0 [m].")
@click.option("--distance", "distance_m", type=float, required=True, metavar="M",
              help="Object distance Z in front of the main lens [m]; must exceed its focal length.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              metavar="FILE", help="Figure file (.png, .pdf or .svg). The numbers go to a JSON "
              "sidecar beside it (same name, .json).")
@click.option("--points", "num_points", type=int, default=5, show_default=True, metavar="N",
              help="Source points evenly spread over the object height, from -h0 to +h0 "
              "[count, >= 1; 1 puts it on the axis].")
@click.option("--rays", "rays_per_point", type=int, default=21, show_default=True, metavar="N",
              help="Rays per source point evenly spread over the main-lens aperture, as in the "
              "paper's figure; most of them miss the ring [count, >= 0].")
@click.option("--rays-per-lens", type=int, default=7, show_default=True, metavar="N",
              help="Further rays per source point and mini-lens, aimed to fill that mini-lens "
              "aperture, so each bundle on the sensor is sampled rim to rim [count, >= 0].")
@device_option
@click.option("--method", type=click.Choice(METHODS), default="fit-sensor", show_default=True,
              help="How b and c are designed for the object and distance (paper Sec. 4.2 "
              "fit-sensor, Sec. 4.1 max-magnification).")
@click.option("--use-device-positions", is_flag=True,
              help="Trace with the b and c stored in the device instead of designing them; the "
              "device must have them, and --method cannot be given with it.")
@click.option("--aperture", type=click.Choice(APERTURES), default="lens", show_default=True,
              help="Main-lens stop: the lens radius RL (as the paper's figure) or the device iris "
              "(aperture_radius_m [m]), which vignettes off-axis points.")
@click.option("--dpi", type=int, default=150, show_default=True, metavar="N",
              help="Resolution of a PNG [dots per inch, 50-600].")
@click.option("--overwrite", is_flag=True, help="Replace an existing figure and sidecar.")
@click.pass_context
def command(ctx, object_size_m, distance_m, output, num_points, rays_per_point, rays_per_lens, device_name,
            method, use_device_positions, aperture, dpi, overwrite):
    """Trace rays through the camera in the meridional plane and draw them (paper Fig. 4).

    Rays leave source points on an object of size --object-size [m] at --distance [m], cross the
    main lens, go through the upper mini-lens a (+hml), the lower mini-lens b (-hml) or miss the
    ring, and meet the sensor. By default the lens positions b and c are designed for this object
    and distance with --method, whatever positions the device holds; --use-device-positions
    traces the device as it is set instead (for example to see defocus at another distance).

    The log gives, for each source point and mini-lens, the convergence spread of the bundle on
    the sensor and its mean hit height against the paraxial image height H2, in micrometres
    (y up, from the optical axis).
    """
    if not 50 <= dpi <= 600:
        raise InvalidInputError(f"--dpi must be between 50 and 600 dots per inch, got {dpi}")
    check_figure_output(output, "-o")
    sidecar = output.with_suffix(".json")
    outputs = OutputSet([output, sidecar], name=output.name, formerly=output.stem, overwrite=overwrite)
    outputs.check()
    device = get_device(device_name)

    if use_device_positions:
        if ctx.get_parameter_source("method") is not click.core.ParameterSource.DEFAULT:
            raise InvalidInputError(
                "--method designs b and c, and --use-device-positions keeps the device's own: "
                "give one of them"
            )
        if not device.has_positions:
            raise DeviceError(
                f"device '{device.name}' has no lens positions (ring_distance_m, "
                "sensor_distance_m); drop --use-device-positions to design them for this object"
            )
        numbers = evaluate(device, object_size_m=object_size_m, distance_m=distance_m)
        how = "device positions"
    else:
        numbers = design(device, object_size_m=object_size_m, distance_m=distance_m, method=method)
        device = device.with_positions(numbers.ring_distance_m, numbers.sensor_distance_m)
        how = f"'{method}' design"

    try:  # the counts' bounds are trace's, checked before it traces
        rt = trace(device, object_size_m=object_size_m, distance_m=distance_m, num_points=num_points,
                   rays_per_point=rays_per_point, rays_per_lens=rays_per_lens, aperture=aperture)
    except InvalidInputError as exc:
        raise InvalidInputError(_option_words(str(exc))) from None
    for problem in numbers.problems:
        log.warning("these lens positions break a design limit: %s", problem)
    st = bundle_stats(rt)
    fates = {name: int((rt.lens == code).sum()) for name, code in
             (("lens_a", UPPER), ("lens_b", LOWER), ("missed_ring", MISSED_RING), ("stopped_main", STOPPED_MAIN))}
    b, c = rt.ring_distance_m, rt.sensor_distance_m
    log.info("b = %.3f mm, c = %.3f mm (%s, object %g m at %g m, %s stop %.3g mm)",
             b * 1e3, c * 1e3, how, object_size_m, distance_m, aperture, rt.stop_radius_m * 1e3)
    log.info("%d rays: %d through lens a, %d through lens b, %d missed the ring, %d stopped by the main lens",
             rt.num_rays, fates["lens_a"], fates["lens_b"], fates["missed_ring"], fates["stopped_main"])
    for i, y0 in enumerate(rt.source_heights_m):
        for k, name in ((UPPER, "a"), (LOWER, "b")):
            if st.count[i, k] == 0:
                log.info("source y0 = %+.1f mm, lens %s: no ray reaches the sensor (paraxial %+.3f um)",
                         y0 * 1e3, name, st.paraxial_height_m[i, k] * 1e6)
                continue
            log.info("source y0 = %+.1f mm, lens %s: %d rays, spread %.3f um, mean hit %+.3f um, "
                     "paraxial %+.3f um (error %+.3f um)", y0 * 1e3, name, st.count[i, k],
                     st.spread_m[i, k] * 1e6, st.mean_height_m[i, k] * 1e6,
                     st.paraxial_height_m[i, k] * 1e6,
                     (st.mean_height_m[i, k] - st.paraxial_height_m[i, k]) * 1e6)
    some = st.count > 0
    worst_spread = float(st.spread_m[some].max()) if some.any() else None
    worst_error = float(np.abs(st.mean_height_m - st.paraxial_height_m)[some].max()) if some.any() else None
    if worst_spread is None:
        log.warning("no ray reaches the sensor through a mini-lens; try more --rays or --rays-per-lens")
    else:
        lost = int((~some).sum())
        log.info("largest convergence spread %.3f um, largest |mean hit - paraxial| %.3f um%s",
                 worst_spread * 1e6, worst_error * 1e6,
                 f" (over the {int(some.sum())} of {some.size} source-lens bundles that reach the sensor)" if lost else "")
        if lost:
            log.warning("%d of %d source-lens bundles reach no sensor pixel (%d rays missed the ring, %d were stopped by "
                        "the main lens): the agreement above says nothing of them", lost, some.size, fates["missed_ring"],
                        fates["stopped_main"])

    from lfring.optics.figures import raytrace_figure, save_figure

    title = (f"{device.name}: b = {b * 1e3:.3f} mm, c = {c * 1e3:.3f} mm ({how}); object "
             f"{object_size_m:g} m at Z = {distance_m:g} m; main-lens stop {rt.stop_radius_m * 1e3:.3g} mm")
    figure = raytrace_figure(rt, title=title)
    info = {
        "device": device.name,
        "positions": "device" if use_device_positions else method,
        "object_size_m": float(object_size_m),
        "distance_m": float(distance_m),
        "ring_distance_m": b,
        "sensor_distance_m": c,
        "aperture": aperture,
        "stop_radius_m": rt.stop_radius_m,
        "num_points": rt.num_points,
        "rays_per_point": rays_per_point,
        "rays_per_lens": rays_per_lens,
        "rays": fates,
        "bundles_reaching_sensor": [int(some.sum()), int(some.size)],  # the spread and error are over these
        "max_spread_m": worst_spread,
        "max_height_error_m": worst_error,
        "design_problems": list(numbers.problems),
        "bundles": st.rows(),
        "figure": output.name,
    }
    with outputs.writing() as stage:
        save_figure(figure, stage(output), overwrite=True, dpi=dpi)
        atomic_write_text(stage(sidecar), json.dumps(info, indent=2) + "\n")
    log.info("wrote %s and %s", output, sidecar)
