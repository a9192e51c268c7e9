"""Figures of the design numbers (paper Figs. 7-9): matplotlib Figure objects, no pyplot state."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from lfring.optics.design import Sweep

__all__ = ["sweep_figure"]


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
