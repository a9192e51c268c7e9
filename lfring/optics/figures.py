"""Figures of the optics: the 2D ray trace of the ring camera (paper Figs. 4, 5a, 6a) and the
design numbers over distance (paper Figs. 7-9).

Functions build :class:`matplotlib.figure.Figure` objects directly (Agg canvas, no pyplot state,
safe in threads and batch jobs) and return them; :func:`save_figure` writes one atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from lfring.errors import InvalidInputError
from lfring.io.atomic import atomic_path
from lfring.optics.positions import Sweep
from lfring.optics.raytrace import LOWER, MISSED_RING, STOPPED_MAIN, UPPER, RayTrace, bundle_stats

__all__ = ["FIGURE_SUFFIXES", "RAY_COLOURS", "raytrace_figure", "save_figure", "sweep_figure"]

#: Ray colours by fate: the paper draws lens a orange and lens b green.
RAY_COLOURS = {
    UPPER: "tab:orange",
    LOWER: "tab:green",
    MISSED_RING: "0.55",
    STOPPED_MAIN: "tab:red",
}
_RAY_LABELS = {
    UPPER: "through mini-lens a (upper)",
    LOWER: "through mini-lens b (lower)",
    MISSED_RING: "missed the mini-lenses",
    STOPPED_MAIN: "stopped by the main lens",
}
_LENS_FACE, _LENS_EDGE = "#cfe3f5", "steelblue"
_HOLDER = "0.25"
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def _polylines(z_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays (N, 4) -> one x and one y array in mm, polylines separated by NaN (one plot call)."""
    gap = np.full((z_m.shape[0], 1), np.nan)
    return np.hstack([z_m, gap]).ravel() * 1e3, np.hstack([y_m, gap]).ravel() * 1e3


def _draw_rays(ax, rt: RayTrace, *, lw: float, alpha_missed: float) -> None:
    # Missed and stopped first, so that the bundles that form the images stay on top.
    for code in (STOPPED_MAIN, MISSED_RING, LOWER, UPPER):
        sel = rt.lens == code
        if not sel.any():
            continue
        x, y = _polylines(rt.z_m[sel], rt.y_m[sel])
        faint = code in (MISSED_RING, STOPPED_MAIN)
        ax.plot(
            x, y, color=RAY_COLOURS[code], lw=lw * (0.8 if faint else 1.0),
            alpha=alpha_missed if faint else 0.9, ls=":" if code == STOPPED_MAIN else "-",
            zorder=1 if faint else 2,
        )


def _draw_optics(ax, rt: RayTrace, *, lens_width_mm: float, labels: tuple[str, ...] = ()) -> None:
    """Object, main lens (with iris), ring of mini-lenses and sensor, in mm."""
    dev = rt.device
    b, c = rt.ring_distance_m * 1e3, rt.sensor_distance_m * 1e3
    z0, h0 = -rt.distance_m * 1e3, rt.object_size_m / 2 * 1e3
    rl, rml, hml = dev.main_lens_radius_m * 1e3, dev.mini_lens_radius_m * 1e3, dev.mini_lens_offset_m * 1e3
    w = lens_width_mm
    # Object and its source points.
    ax.plot([z0, z0], [-h0, h0], color="k", lw=2.5, solid_capstyle="butt", zorder=4)
    ax.plot(np.full(rt.num_points, z0), rt.source_heights_m * 1e3, "o", color="k", ms=4, zorder=5)
    # Main lens, and the iris blades when the trace used it.
    ax.add_patch(Rectangle((-w / 2, -rl), w, 2 * rl, fc=_LENS_FACE, ec=_LENS_EDGE, lw=1, zorder=3))
    if rt.stop_radius_m < dev.main_lens_radius_m:
        s = rt.stop_radius_m * 1e3
        for lo, hi in ((s, rl), (-rl, -s)):
            ax.plot([0, 0], [lo, hi], color=_HOLDER, lw=3, solid_capstyle="butt", zorder=4)
    # Ring: the two mini-lenses of the plane in an opaque holder.
    holder = max(hml + 2 * rml, rl * 0.25)
    for lo, hi in ((hml + rml, holder), (-holder, -(hml + rml)), (-(hml - rml), hml - rml)):
        if hi > lo:
            ax.plot([b, b], [lo, hi], color=_HOLDER, lw=3, solid_capstyle="butt", zorder=4)
    for m in rt.lens_centres_m * 1e3:
        ax.add_patch(Rectangle((b - w / 2, m - rml), w, 2 * rml, fc=_LENS_FACE, ec=_LENS_EDGE, lw=1, zorder=3))
    # Sensor.
    hs = dev.sensor_height_m * 1e3
    ax.plot([b + c, b + c], [-hs / 2, hs / 2], color="k", lw=4, solid_capstyle="butt", zorder=4)
    ax.axhline(0.0, color="k", lw=0.6, ls="-.", alpha=0.5, zorder=0)
    kw = dict(fontsize=8, ha="center", va="bottom", zorder=6, clip_on=True)
    where = {"object": (z0, h0 * 1.04), "main lens": (0, rl * 1.03), "ring": (b, holder * 1.1),
             "sensor": (b + c, hs / 2 * 1.15)}
    for name in labels:
        ax.text(*where[name], name, **kw)


def _intermediate_image(ax, rt: RayTrace) -> None:
    fl, z = rt.device.main_focal_length_m, rt.distance_m
    b1 = z * fl / (z - fl) * 1e3
    ax.axvline(b1, color="tab:purple", lw=0.8, ls="--", alpha=0.7, zorder=0)
    ax.text(b1, 0.02, " intermediate\n image b1", transform=ax.get_xaxis_transform(), fontsize=7,
            color="tab:purple", va="bottom")


def raytrace_figure(rt: RayTrace, *, title: str | None = None, zoom_half_height_m: float | None = None) -> Figure:
    """Figure of a ray trace: the whole system, the camera, and a zoom on the ring and sensor.

    Parameters
    ----------
    rt : RayTrace
        From :func:`lfring.optics.raytrace.trace`.
    title : str, optional
        Figure title; default names the device, b, c, the object and its distance.
    zoom_half_height_m : float, optional
        Half-height of the sensor zoom; default 1.2 x hs/2 (enough for all four image edges).

    Returns
    -------
    matplotlib.figure.Figure
        Three panels in millimetres, y up: (a) the whole system at true scale, object included;
        (b) the camera from the main lens to the sensor; (c) the ring and sensor, where the
        bundles through each mini-lens converge, with the mean hit of each bundle marked and
        the paraxial image heights ticked; (d) the sensor around the top of the upper image
        (H2,a), where the bundle of the top object point converges, or spreads when defocused.
    """
    if not isinstance(rt, RayTrace):
        raise InvalidInputError(f"expected a RayTrace from lfring.optics.raytrace.trace(), got {type(rt).__name__}")
    dev = rt.device
    b, c = rt.ring_distance_m * 1e3, rt.sensor_distance_m * 1e3
    z0, h0 = -rt.distance_m * 1e3, rt.object_size_m / 2 * 1e3
    rl, hs = dev.main_lens_radius_m * 1e3, dev.sensor_height_m * 1e3
    st = bundle_stats(rt)

    fig = Figure(figsize=(13, 9.5), layout="constrained")
    grid = fig.add_gridspec(2, 5, height_ratios=[1, 1.35])
    ax_all = fig.add_subplot(grid[0, :4])
    ax_top = fig.add_subplot(grid[0, 4])
    ax_cam = fig.add_subplot(grid[1, :3])
    ax_zoom = fig.add_subplot(grid[1, 3:])

    # (a) whole system, true scale.
    span = b + c - z0
    _draw_rays(ax_all, rt, lw=0.6, alpha_missed=0.35)
    _draw_optics(ax_all, rt, lens_width_mm=span * 0.004, labels=("object", "main lens", "ring"))
    ax_all.set_xlim(z0 - 0.03 * span, b + c + 0.03 * span)
    ylim = 1.15 * max(h0, rl)
    ax_all.set_ylim(-ylim, ylim)
    ax_all.set_title("(a) whole system, true scale", fontsize=10, loc="left")

    # (b) the camera.
    cam_span = b + c
    _draw_rays(ax_cam, rt, lw=0.7, alpha_missed=0.35)
    _draw_optics(ax_cam, rt, lens_width_mm=cam_span * 0.008, labels=("main lens", "ring", "sensor"))
    _intermediate_image(ax_cam, rt)
    ax_cam.set_xlim(-0.06 * cam_span, b + c + 0.04 * cam_span)
    reach = np.nanmax(np.abs(rt.y_m[:, 1:])) * 1e3 if np.isfinite(rt.y_m[:, 1:]).any() else rl
    ylim = 1.12 * max(rl, min(reach, 2.0 * rl))
    ax_cam.set_ylim(-ylim, ylim)
    ax_cam.set_title("(b) camera: main lens, ring and sensor", fontsize=10, loc="left")

    # (c) ring and sensor.
    half = (1.2 * hs / 2) if zoom_half_height_m is None else zoom_half_height_m * 1e3
    _draw_rays(ax_zoom, rt, lw=0.8, alpha_missed=0.5)
    _draw_optics(ax_zoom, rt, lens_width_mm=c * 0.03)
    ax_zoom.set_xlim(b - 0.35 * c, b + c + 0.12 * c)
    ax_zoom.set_ylim(-half, half)
    ax_zoom.text(b + 0.03 * c, half * 0.98, " ring", fontsize=8, ha="left", va="top")
    ax_zoom.text(b + c, half * 0.98, "sensor", fontsize=8, ha="center", va="top")
    ax_zoom.set_title("(c) zoom: convergence on the sensor", fontsize=10, loc="left")
    zs = b + c
    for k in (UPPER, LOWER):
        ok = st.count[:, k] > 0
        ax_zoom.plot(np.full(ok.sum(), zs), st.mean_height_m[ok, k] * 1e3, "o", ms=4, mfc="none",
                     mec=RAY_COLOURS[k], mew=1.2, zorder=6)
        ax_zoom.plot(np.full(rt.num_points, zs + 0.05 * c), st.paraxial_height_m[:, k] * 1e3, "<",
                     ms=4, color="k", zorder=6)
    top_i = int(np.argmax(rt.source_heights_m))
    h2a, h2b = st.paraxial_height_m[top_i]
    ax_zoom.annotate(f"H2,a = {h2a * 1e3:.3f} mm", (zs + 0.06 * c, h2a * 1e3), fontsize=8,
                     xytext=(zs - 0.55 * c, min(h2a * 1e3 + 0.12 * half, half * 0.9)),
                     arrowprops=dict(arrowstyle="-", lw=0.6))
    ax_zoom.annotate(f"H2,b = {h2b * 1e3:.3f} mm", (zs + 0.06 * c, h2b * 1e3), fontsize=8,
                     xytext=(zs - 0.55 * c, h2b * 1e3 + 0.15 * half), arrowprops=dict(arrowstyle="-", lw=0.6))
    spread = st.spread_m[st.count > 0]
    worst = float(spread.max()) if spread.size else float("nan")
    ax_zoom.text(0.02, 0.02, f"largest bundle spread on the sensor: {worst * 1e6:.3g} um\n"
                 "o: mean hit of each bundle   <: paraxial image height",
                 transform=ax_zoom.transAxes, fontsize=7.5, va="bottom",
                 bbox=dict(fc="white", ec="0.7", alpha=0.9))

    # (d) the sensor around the top of the upper image, where the top object point converges.
    ax_top.plot([zs, zs], [-hs / 2, hs / 2], color="k", lw=4, solid_capstyle="butt", zorder=4)
    if st.count[top_i, UPPER] > 0:
        _draw_rays(ax_top, rt, lw=0.9, alpha_missed=0.5)
        centre = st.mean_height_m[top_i, UPPER] * 1e3
        dy = max(2.0 * float(st.spread_m[top_i, UPPER]) * 1e3, 0.02)
        # Deep enough in z that the converging cone (slopes up to Rml / c) fills the window.
        dz = min(0.8 * dy * c / (dev.mini_lens_radius_m * 1e3), 0.5 * c)
        ax_top.plot([zs], [centre], "o", ms=6, mfc="none", mec=RAY_COLOURS[UPPER], mew=1.5, zorder=6)
        ax_top.plot([zs + 0.08 * dz], [h2a * 1e3], "<", ms=7, color="k", zorder=6)
        ax_top.set_xlim(zs - dz, zs + 0.15 * dz)
        ax_top.set_ylim(centre - dy, centre + dy)
        ax_top.text(0.03, 0.03, f"spread {float(st.spread_m[top_i, UPPER]) * 1e6:.3g} um\n"
                    f"mean {centre:.4f} mm\nH2,a {h2a * 1e3:.4f} mm", transform=ax_top.transAxes,
                    fontsize=7.5, va="bottom", bbox=dict(fc="white", ec="0.7", alpha=0.9))
    else:
        ax_top.text(0.5, 0.5, "no ray of the top object point\nreaches mini-lens a", ha="center",
                    transform=ax_top.transAxes, fontsize=8)
        ax_top.set_xlim(zs - 0.5 * c, zs + 0.1 * c)
        ax_top.set_ylim(h2a * 1e3 - 0.2, h2a * 1e3 + 0.2)
    ax_top.set_title("(d) top of image a", fontsize=10, loc="left")

    for ax in (ax_all, ax_top, ax_cam, ax_zoom):
        ax.set_xlabel("z [mm] (main lens at 0)")
        ax.set_ylabel("y [mm] (up)")
        ax.grid(True, alpha=0.2)
    handles = [Line2D([], [], color=RAY_COLOURS[k], lw=1.5, ls=":" if k == STOPPED_MAIN else "-",
                      label=_RAY_LABELS[k]) for k in (UPPER, LOWER, MISSED_RING, STOPPED_MAIN)
               if (rt.lens == k).any()]
    ax_all.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.9)
    if title is None:
        title = (
            f"{dev.name}: b = {b:.3f} mm, c = {c:.3f} mm; object {rt.object_size_m * 1e3:.4g} mm "
            f"at Z = {rt.distance_m * 1e3:.4g} mm; main-lens stop {rt.stop_radius_m * 1e3:.4g} mm "
            f"({rt.aperture})"
        )
    fig.suptitle(title, fontsize=11)
    return fig


def save_figure(fig: Figure, path: str | Path, *, overwrite: bool = False, dpi: int = 150) -> Path:
    """Write ``fig`` to ``path`` (.png, .pdf or .svg) atomically; an existing file is kept unless
    ``overwrite``.

    Raises
    ------
    InvalidInputError
        Unsupported suffix, or the file exists and ``overwrite`` is False.
    """
    path = Path(path)
    if path.suffix.lower() not in FIGURE_SUFFIXES:
        raise InvalidInputError(f"figure file must end in {', '.join(FIGURE_SUFFIXES)}; got {path.name!r}")
    if path.exists() and not overwrite:
        raise InvalidInputError(f"{path} exists; pass overwrite=True to replace it")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lower()[1:])
    return path


# -- design numbers over distance (paper Figs. 7-9) ----------------------------------------
def _shade_invalid(ax, z: np.ndarray, valid: np.ndarray) -> None:
    """Grey bands over the distances where the design breaks a validity limit."""
    if valid.all():
        return
    edges = np.concatenate([[z[0]], (z[1:] + z[:-1]) / 2, [z[-1]]])
    first = True
    for i in np.flatnonzero(~valid):
        ax.axvspan(edges[i], edges[i + 1], color="0.85", lw=0, label="invalid" if first else None)
        first = False


def _labelled(*axes) -> list:
    return [ln for ax in axes for ln in ax.get_lines() if not ln.get_label().startswith("_")]


def sweep_figure(sw: Sweep, *, title: str = "", mark_distance_m: float | None = None) -> Figure:
    """Four panels over distance: b and c; magnification; disparity and overlap; depth resolution
    and blur. Distances where the design is invalid are shaded and listed in the legend."""
    z = sw.distance_m.ravel()
    order = np.argsort(z)
    z = z[order]
    valid = sw.valid.ravel()[order]

    def col(a):
        return np.broadcast_to(a, sw.distance_m.shape).ravel()[order]

    fig = Figure(figsize=(11, 7.5), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    (a_bc, a_g), (a_d, a_r) = axes
    for ax in axes.ravel():
        _shade_invalid(ax, z, valid)
        if mark_distance_m is not None:
            ax.axvline(mark_distance_m, color="k", ls=":", lw=1)
        ax.grid(True, alpha=0.3)
    a_bc.plot(z, col(sw.ring_distance_m) * 1e3, label="b (main lens to ring)")
    a_bc.plot(z, col(sw.sensor_distance_m) * 1e3, label="c (ring to sensor)")
    a_bc.set_ylabel("distance [mm]")
    a_bc.legend()
    # Ia = G * 2 h0 is the same curve scaled, so it gets a second axis, not a second line.
    a_g.plot(z, col(sw.magnification), color="C2", label="G")
    a_g.set_ylabel("magnification G")
    size = float(np.ravel(sw.object_size_m)[0])
    if np.allclose(sw.object_size_m, size):
        a_g.secondary_yaxis("right", functions=(lambda g: g * size * 1e3, lambda ia: ia / (size * 1e3))).set_ylabel(
            "image height Ia [mm]"
        )
    a_d.plot(z, col(sw.disparity_px), color="C0", label="disparity d")
    a_d.set_ylabel("disparity d [px]")
    a_d.set_xlabel("object distance Z [m]")
    a_d2 = a_d.twinx()
    a_d2.plot(z, col(sw.overlap), color="C1", ls="--", label="overlap o")
    a_d2.set_ylabel("overlap o")
    a_d.legend(handles=_labelled(a_d, a_d2), loc="upper right")
    a_r.plot(z, col(sw.depth_resolution_m_per_px) * 1e3, color="C4", label="depth per px of disparity")
    a_r.set_ylabel("depth resolution [mm/px]")
    a_r.set_xlabel("object distance Z [m]")
    lines = _labelled(a_r)
    if sw.fixed:  # redesigned at every distance, the plane is always in focus: no blur to show
        a_r2 = a_r.twinx()
        blur = col(sw.blur_px)
        a_r2.plot(z, np.where(np.isfinite(blur), blur, np.nan), color="C5", ls="--", label="defocus blur")
        a_r2.set_ylabel("blur diameter [px]")
        lines = lines + _labelled(a_r2)
    a_r.legend(handles=lines, loc="upper left")
    if not valid.all():
        a_bc.text(0.01, 0.02, "grey: design invalid", transform=a_bc.transAxes, fontsize=8, color="0.3")
    fig.suptitle(title or ("fixed b, c" if sw.fixed else f"design by '{sw.method}' at every distance"))
    return fig
