"""``lfring design``: lens positions (paper Secs. 4.1-4.2), sweeps and working-range designs."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import SWEEP_METAVAR, check_figure_output, device_option, get_device, parse_range
from lfring.optics.positions import METHODS, design, design_working_range, sweep

log = logging.getLogger("lfring.cli.design")

_ROWS = (
    ("ring_distance_m", "ring distance b (main lens to ring)", 1e3, "mm", "{:.3f}"),
    ("sensor_distance_m", "sensor distance c (ring to sensor)", 1e3, "mm", "{:.3f}"),
    ("mount_distance_m", "mount distance B", 1e3, "mm", "{:.3f}"),
    ("entrance_pupil_m", "view entrance pupil s (in front of lens)", 1e3, "mm", "{:.3f}"),
    ("magnification", "magnification G", 1.0, "", "{:.5f}"),
    ("image_height_m", "image height Ia", 1e3, "mm", "{:.4f}"),
    ("upper_image_top_m", "upper image top H2,a", 1e3, "mm", "{:.4f}"),
    ("disparity_px", "disparity d (vertical neighbours)", 1.0, "px", "{:.1f}"),
    ("disparity_horizontal_px", "disparity (horizontal neighbours)", 1.0, "px", "{:.1f}"),
    ("overlap", "overlap o", 1.0, "", "{:.3f}"),
    ("depth_resolution_m_per_px", "depth per px of disparity", 1e3, "mm/px", "{:.3f}"),
    ("blur_px", "defocus blur diameter", 1.0, "px", "{:.2f}"),
)


_RANGE_METAVAR = "NEAR:FAR"
"""The parts of --range as the help names them, and so the messages."""


def _plot_outputs(plot: str | None, overwrite: bool):
    """The --plot file as an output set checked before any work (its suffix, and a file there
    that may not be replaced), so that a refusal does not follow the printed numbers; None
    without --plot."""
    if not plot:
        return None
    from lfring.cli.outputs import OutputSet

    check_figure_output(plot, "--plot")
    outputs = OutputSet([plot], name=Path(plot).name, overwrite=overwrite)
    outputs.check()
    return outputs


def _save_figure(fig, path: str, outputs) -> None:
    from lfring.optics.figures import save_figure

    with outputs.writing() as stage:
        save_figure(fig, stage(path), overwrite=True)
    log.info("wrote %s", path)


@click.command("design")
@click.option("--object-size", type=float, required=True, metavar="M", help="Object size 2*h0 [m].")
@click.option("--distance", type=float, default=None, metavar="M", help="Object distance Z from the main lens [m].")
@click.option("--sweep", "sweep_spec", default=None, metavar=SWEEP_METAVAR,
              help="Redesign at N distances from START to STOP [m] (paper Figs. 7-9).")
@click.option("--range", "range_spec", default=None, metavar=_RANGE_METAVAR,
              help="Working-range design for objects from NEAR to FAR [m].")
@device_option
@click.option("--method", type=click.Choice(METHODS), default="fit-sensor", show_default=True,
              help="Lens-position method (paper Sec. 4.2 fit-sensor, Sec. 4.1 max-magnification).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
@click.option("--plot", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Also write a figure (PNG/PDF/SVG) of the numbers over distance.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --plot file.")
def command(object_size, distance, sweep_spec, range_spec, device_name, method, as_json, plot, overwrite):
    """Lens positions b, c and imaging numbers for an object of a given size.

    Exactly one of --distance, --sweep or --range. Lengths are in metres on input; the table
    shows millimetres, the JSON keeps metres (keys carry the unit).
    """
    chosen = [x is not None for x in (distance, sweep_spec, range_spec)]
    if sum(chosen) != 1:
        raise click.UsageError(f"give exactly one of --distance, --sweep {SWEEP_METAVAR} or --range {_RANGE_METAVAR}")
    if sweep_spec is not None:
        start, stop, count = parse_range(sweep_spec, with_count=True, param_hint="--sweep", metavar=SWEEP_METAVAR)
    elif range_spec is not None:
        near, far = parse_range(range_spec, with_count=False, param_hint="--range", metavar=_RANGE_METAVAR)
    outputs = _plot_outputs(plot, overwrite)
    device = get_device(device_name)
    if device.has_positions:
        log.info("the positions device '%s' is set to (b %.3f mm, c %.3f mm) are not these: design places the lenses for "
                 "the object and distance given (lfring raytrace --use-device-positions traces the device as set)",
                 device.name, device.ring_distance_m * 1e3, device.sensor_distance_m * 1e3)
    if device.flange_focal_distance_m == 0.0:
        log.warning("device '%s' gives no flange_focal_distance_m: the mount distance B below takes it as 0",
                    device.name)
    if distance is not None:
        d = design(device, object_size_m=object_size, distance_m=distance, method=method)
        _report_design(d, device.name, as_json)
        if plot:
            from lfring.optics.figures import sweep_figure

            dev = device.with_positions(d.ring_distance_m, d.sensor_distance_m)
            lo = max(distance / 3.0, device.main_focal_length_m * 1.5)
            sw = sweep(dev, object_size_m=object_size, distances_m=np.geomspace(lo, distance * 10, 200), fixed=True)
            fig = sweep_figure(sw, mark_distance_m=distance,
                               title=f"b = {d.ring_distance_m * 1e3:.2f} mm, c = {d.sensor_distance_m * 1e3:.3f} mm "
                                     f"(designed for {object_size} m at {distance} m), numbers over distance")
            _save_figure(fig, plot, outputs)
    elif sweep_spec is not None:
        sw = sweep(device, object_size_m=object_size, distances_m=np.linspace(start, stop, count), method=method)
        _report_sweep(sw, as_json, {"method": method, "device": device.name, "object_size_m": object_size})
        if plot:
            from lfring.optics.figures import sweep_figure

            _save_figure(sweep_figure(sw, title=f"'{method}' design for a {object_size} m object"), plot, outputs)
    else:
        wr = design_working_range(device, object_size_m=object_size, near_m=near, far_m=far)
        head = {
            "device": device.name,
            "object_size_m": wr.object_size_m,
            "near_m": wr.near_m,
            "far_m": wr.far_m,
            "ring_distance_m": wr.ring_distance_m,
            "sensor_distance_m": wr.sensor_distance_m,
            "mount_distance_m": wr.mount_distance_m,
            "entrance_pupil_m": wr.entrance_pupil_m,
            "focus_distance_m": wr.focus_distance_m,
        }
        if not as_json:
            click.echo(f"Working range {near:g} m to {far:g} m for a {object_size:g} m object (device {device.name})")
            click.echo(f"  ring distance b    {wr.ring_distance_m * 1e3:9.3f} mm")
            click.echo(f"  sensor distance c  {wr.sensor_distance_m * 1e3:9.3f} mm")
            click.echo(f"  mount distance B   {wr.mount_distance_m * 1e3:9.3f} mm")
            click.echo(f"  sharpest at Z      {wr.focus_distance_m:9.3f} m")
        _report_sweep(wr.sweep, as_json, head)
        if plot:
            from lfring.optics.figures import sweep_figure

            fig = sweep_figure(wr.sweep, title=f"working range {near:g}-{far:g} m: b = {wr.ring_distance_m * 1e3:.2f} mm, "
                                                f"c = {wr.sensor_distance_m * 1e3:.3f} mm")
            _save_figure(fig, plot, outputs)


def _report_design(d, device_name: str, as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps({"device": device_name, **d.to_dict()}, indent=2))
    else:
        click.echo(f"Design '{d.method}' for a {d.object_size_m:g} m object at {d.distance_m:g} m (device {device_name})")
        for key, label, scale, unit, fmt in _ROWS:
            click.echo(f"  {label:<42s} {fmt.format(getattr(d, key) * scale):>10s} {unit}")
    for p in d.problems:
        log.warning("design invalid: %s", p)


def _report_sweep(sw, as_json: bool, head: dict) -> None:
    rows = sw.points()
    if as_json:
        click.echo(json.dumps({**head, "fixed_positions": sw.fixed, "points": rows}, indent=2))
    else:
        click.echo(f"{'Z [m]':>8} {'b [mm]':>8} {'c [mm]':>7} {'G':>8} {'Ia [mm]':>8} {'d [px]':>8} "
                   f"{'o':>7} {'mm/px':>7} {'blur px':>8}  validity")
        for r in rows:
            click.echo(
                f"{r['distance_m']:8.3f} {r['ring_distance_m'] * 1e3:8.3f} {r['sensor_distance_m'] * 1e3:7.3f} "
                f"{r['magnification']:8.5f} {r['image_height_m'] * 1e3:8.4f} {r['disparity_px']:8.1f} "
                f"{r['overlap']:7.3f} {r['depth_resolution_m_per_px'] * 1e3:7.2f} {r['blur_px']:8.2f}  "
                + ("ok" if r["valid"] else "; ".join(p.split(" at Z=")[0] for p in r["problems"]))
            )
    bad = int((~sw.valid).sum())
    if bad:
        log.warning("%d of %d points break a validity limit (listed per point)", bad, len(rows))
