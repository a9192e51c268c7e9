"""Specks and seams of depth-aware refocusing on the README's main job: the bundled frame
(`data/synthetic/scene.png`), its built-in calibration, the depth map `lfring refocus` makes.

A speck is a pixel of the image, where some view sees it, that is darker (or brighter) than the
median of its 5 x 5 neighbourhood by more than 0.15 (linear [0, 1]). Thin dark lines along the
views' disc rims and dark dots inside flat regions are what users saw; an edge of the scene
itself (a corner of a chessboard square, a highlight) can also count, so compare counts between
trees or settings, not against zero. Counted for the renderer's all-in-focus colour and for
renders at three foci and apertures, with the views split three ways: with no flat field, with
the calibration's own (as the main job runs, when it carries one) and with the bundled flat
frame. Beside them, the depth of each setting (view 0, estimated at the defaults over the
calibration's range) against the bundled truth: the share of view 0's pixels estimated, and of
those the share more than 5 % off. Last, the main job's image (0.5 m, aperture 1) against what a
lens of that aperture records of the same scene (``lfring.synth.render_conventional`` of the
preset the frame was made from, times its exposure, registered to the image by phase
correlation: the built-in calibration's central frame lies a fraction of a pixel from the
synthetic one), on the pixels two or more views see and on the rims that one to two views see,
shift-and-add beside it; and the all-in-focus images against a pinhole's. The truth has
neither the views' own defocus nor their noise, so the figures are low in absolute terms:
compare trees.

    python benchmarks/bench_refocus_specks.py

To compare two trees, run it with each first on PYTHONPATH.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import tifffile

from lfring import demosaic, estimate_depth, refocus, split_views
from lfring.calibration.defaults import default_calibration
from lfring.check import check_frame
from lfring.focus.depth_aware import depth_of_field, estimation_range
from lfring.io.levels import load_frame
from lfring.views import flat_field_from_frame

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"
# A speck: this much (linear [0, 1]) off the median of its 5 x 5 neighbourhood.
SPECK = 0.15
# A depth more than this fraction off the truth is a bad pixel.
BAD_REL = 0.05
RENDERS = ((0.5, 1.0), (0.3, 2.0), (1.0, 1.0))


def specks(image: np.ndarray, seen: np.ndarray) -> tuple[int, int]:
    """(dark, bright) speck counts of ``image`` (h, w, C) over the ``seen`` pixels."""
    g = image.mean(axis=2)
    med = cv2.medianBlur(np.clip(g * 255.0, 0, 255).astype(np.uint8), 5).astype(np.float32) / 255.0
    return int((seen & (med - g > SPECK)).sum()), int((seen & (g - med > SPECK)).sum())


def depth_accuracy(views, cal, truth: np.ndarray, zmin: float, zmax: float) -> tuple[float, float]:
    """(% of view 0's ``truth`` pixels estimated, % of those more than BAD_REL off) for view 0's
    depth at the defaults (the truth is 704 x 704 px, the views' top-left part)."""
    h, w = truth.shape
    depth = estimate_depth(views, cal, zmin_m=zmin, zmax_m=zmax, reference=0).depth_m[:h, :w]
    known = np.isfinite(truth) & (truth > 0)
    est = known & np.isfinite(depth)
    rel = np.abs(depth[est] - truth[est]) / truth[est]
    return 100.0 * est.sum() / known.sum(), 100.0 * float((rel > BAD_REL).mean())


def conventional(focus_m: float, **aperture) -> np.ndarray:
    """The conventional image of the bundled scene focused at ``focus_m`` (``aperture``:
    ``render_conventional``'s), times the frame's exposure."""
    import json

    from lfring.optics import load_device
    from lfring.synth import render_conventional
    from lfring.synth.presets import three_depth_scene

    settings = json.loads((DATA / "scene_truth" / "truth.json").read_text())["settings"]
    truth = settings["exposure"] * render_conventional(three_depth_scene(), load_device("prototype"), focus_m,
                                                       binning=settings["binning"], **aperture)
    return truth.astype(np.float32)


def moved(image: np.ndarray, shift) -> np.ndarray:
    """``image`` moved by ``shift`` (dx, dy) px, bicubically."""
    h, w = image.shape[:2]
    return cv2.warpAffine(image, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (w, h), flags=cv2.INTER_CUBIC)


def psnr_table(images: dict, truth: np.ndarray, masks: dict) -> None:
    """One row a named image: its PSNR (dB) against ``truth`` on each mask."""
    h, w = truth.shape[:2]
    print("| image | " + " | ".join(masks) + " |")
    print("|---|" + "---|" * len(masks))
    for name, img in images.items():
        psnr = [10 * np.log10(1.0 / np.mean((np.clip(img[:h, :w], 0, 1) - truth)[m] ** 2)) for m in masks.values()]
        print(f"| {name} | " + " | ".join(f"{p:.2f}" for p in psnr) + " |")


def truth_table(views, cal, depth_aware: np.ndarray, depth) -> None:
    """The main job's ``depth_aware`` image (RENDERS[0] of ``views``) and shift-and-add against
    the conventional image of the bundled scene, then the all-in-focus images from the main
    job's ``depth`` estimate against a pinhole's (see the module's description)."""
    from lfring.focus import Refocuser, all_in_focus

    focus, aperture = RENDERS[0]
    truth = conventional(focus, aperture_scale=aperture)
    h, w = truth.shape[:2]
    sa = refocus(views, cal, focus)[:h, :w]
    grey = lambda img: np.ascontiguousarray(img.mean(axis=2), np.float32)
    shift, _ = cv2.phaseCorrelate(grey(truth), grey(sa), cv2.createHanningWindow((w, h), cv2.CV_32F))
    weight = Refocuser(cal, focus).weight[:h, :w]
    inner = np.zeros((h, w), bool)
    inner[12:-12, 12:-12] = True  # the registration's border left out
    masks = {"two or more views": inner & (weight >= 2.0), "one to two views (the rims)": inner & (weight >= 1.0) & (weight < 2.0)}
    print(f"\nThe main job's image ({focus:g} m, aperture {aperture:g}) against the conventional image, registered by "
          f"({shift[0]:.2f}, {shift[1]:.2f}) px: PSNR (dB; the masks hold "
          + ", ".join(f"{100 * m.mean():.0f} %" for m in masks.values()) + " of the frame)")
    psnr_table({"shift-and-add": sa, "depth-aware (the main job)": depth_aware}, moved(truth, shift), masks)
    # The all-in-focus images: from the estimate as its DepthResult (as the CLI, batches and the
    # viewer pass it; also snapped to its hypotheses), as its bare depth_m array, and by the
    # views' photo-consistency without a map.
    print("\nThe all-in-focus images against a pinhole's conventional image: PSNR (dB)")
    psnr_table({"from the depth result (the CLI's, batches', the viewer's)": all_in_focus(views, cal, depth_map_m=depth)[0],
                "from the depth result, snapped to its hypotheses": all_in_focus(views, cal, depth.depths_m,
                                                                                 depth_map_m=depth)[0],
                "from its depth_m array": all_in_focus(views, cal, depth_map_m=depth.depth_m)[0],
                "by photo-consistency": all_in_focus(views, cal)[0]},
               moved(conventional(focus, f_number=np.inf), shift), masks)


def main() -> None:
    probe, _ = load_frame(DATA / "scene.png")
    image = demosaic(probe)
    cal, cal_name = default_calibration((image.shape[1], image.shape[0]))
    assert check_frame(image, cal).ok
    frame, _ = load_frame(DATA / "scene.png", calibration=cal)
    image = demosaic(frame)
    flat_frame = demosaic(load_frame(DATA / "flat.png", calibration=cal)[0])
    zmin, zmax = estimation_range(cal)
    bare = dataclasses.replace(cal, flat_field=None)
    settings = [("none", split_views(image, bare))]
    if cal.flat_field is not None:
        settings.append(("the calibration's (the main job)", split_views(image, cal)))
    else:
        settings[0] = ("none (the main job)", settings[0][1])
    settings.append(("flat.png", split_views(image, cal, flat=flat_field_from_frame(flat_frame, cal))))
    print(f"scene.png, built-in calibration {cal_name} ({'with' if cal.flat_field is not None else 'without'} a flat "
          f"field), depth range {zmin:.3g} .. {zmax:.3g} m; speck: {SPECK} off the 5 x 5 median")
    print(f"| flat field | view 0's depth: % estimated, % of those > {BAD_REL:.0%} off |")
    print("|---|---|")
    truth = tifffile.imread(DATA / "scene_truth" / "depth_view0.tiff")
    for label, views in settings:
        done, bad = depth_accuracy(views, cal, truth, zmin, zmax)
        print(f"| {label} | {done:.1f} %, {bad:.2f} % |")
    print()
    print("| flat field | image | dark specks | bright specks | pixels seen |")
    print("|---|---|---|---|---|")
    main_job = settings[1 if cal.flat_field is not None else 0][0]
    for label, views in settings:
        depth = estimate_depth(views, cal, zmin_m=zmin, zmax_m=zmax)
        dof = depth_of_field(views, cal, depth=depth)
        renders = [dof.render(f, a, refocus(views, cal, f)) for f, a in RENDERS]
        rows = [("all-in-focus colour", dof.colour)]
        rows += [(f"render at {f:g} m, aperture {a:g}", img) for (f, a), img in zip(RENDERS, renders)]
        for what, img in rows:
            dark, bright = specks(img, dof.seen)
            print(f"| {label} | {what} | {dark} | {bright} | {int(dof.seen.sum())} |")
        if label == main_job:
            job = (views, renders[0], depth)
    truth_table(job[0], cal, job[1], job[2])


if __name__ == "__main__":
    main()
