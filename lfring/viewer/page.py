"""Build the viewer page: the images and maps, encoded inline, poured into template.html."""

from __future__ import annotations

import base64
import html
import json
import re
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from lfring.core.validate import check_choice, check_fraction, check_int, check_number, is_number
from lfring.core.viewstack import check_views
from lfring.depth import SGM_MIN_PLANES
from lfring.errors import InvalidInputError
from lfring.core.protocols import check_calibration

#: Image formats of the focal stack and the all-in-focus image: (cv2 suffix, MIME type, quality flag).
IMAGE_FORMATS = {
    "jpeg": (".jpg", "image/jpeg", cv2.IMWRITE_JPEG_QUALITY),
    "webp": (".webp", "image/webp", cv2.IMWRITE_WEBP_QUALITY),
}
#: Samples of the depth colour bar (near to far).
COLOUR_BAR_STOPS = 17
#: Opacity of the low-confidence shading and of the unchecked-area overlay.
SHADE_ALPHA = 0.55


def _template() -> str:
    return resources.files("lfring.viewer").joinpath("template.html").read_text(encoding="utf-8")


def _data_uri(mime: str, data: bytes) -> str:
    return f"data:{mime};base64," + base64.b64encode(data).decode("ascii")


def _encode(image_u8: np.ndarray, suffix: str, params=()) -> bytes:
    arr = image_u8
    if arr.ndim == 3 and arr.shape[2] == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(suffix, np.ascontiguousarray(arr), list(params))
    if not ok:  # pragma: no cover - OpenCV builds without a codec
        raise InvalidInputError(f"this OpenCV build cannot encode {suffix} images; choose another image_format")
    return buf.tobytes()


BOX_COLOUR = "#ff2d2d"
"""A box's colour where none is given."""


def _check_boxes(boxes) -> list[dict]:
    """(x, y, w, h), (x, y, w, h, label) or (x, y, w, h, label, colour) in reference pixels,
    ``colour`` '#rrggbb' -> JSON-ready dicts."""
    out = []
    for i, b in enumerate(boxes or ()):
        if isinstance(b, dict):
            b = (b["x"], b["y"], b["w"], b["h"], b.get("label", ""), b.get("colour", BOX_COLOUR))
        if len(b) not in (4, 5, 6) or not all(is_number(v) and np.isfinite(v) for v in b[:4]):
            raise InvalidInputError(f"boxes[{i}] must be (x, y, w, h), (x, y, w, h, label) or (x, y, w, h, label, "
                                    f"colour) in pixels, got {b!r}")
        x, y, w, h = (float(v) for v in b[:4])
        if w <= 0 or h <= 0:
            raise InvalidInputError(f"boxes[{i}] must have a positive width and height, got {b!r}")
        colour = str(b[5]) if len(b) == 6 else BOX_COLOUR
        if not re.fullmatch(r"#[0-9a-fA-F]{6}", colour):
            raise InvalidInputError(f"boxes[{i}]'s colour must be '#rrggbb', got {colour!r}")
        out.append({"x": x, "y": y, "w": w, "h": h, "label": str(b[4]) if len(b) >= 5 else "", "colour": colour})
    return out


def _overlay_png(mask, shape_hw) -> str:
    """A boolean (h, w) mask as a translucent amber PNG data: URI."""
    m = np.asarray(mask)
    if m.shape != shape_hw or m.dtype != bool:
        raise InvalidInputError(f"unchecked_mask must be a {shape_hw[0]} x {shape_hw[1]} boolean array "
                                f"(the reference frame), got {m.dtype} {m.shape}")
    rgba = np.zeros((*shape_hw, 4), np.uint8)
    rgba[m] = (255, 200, 0, int(round(255 * SHADE_ALPHA)))
    return _data_uri("image/png", _encode(rgba, ".png"))


def _check_options(num_planes, min_confidence, image_format, quality):
    check_int(num_planes, "num_planes", minimum=SGM_MIN_PLANES, allow_none=True,
              hint=" (the depth map's semi-global method judges each answer against farther hypotheses)")
    check_fraction(min_confidence, "min_confidence")
    check_choice(image_format, "image_format", IMAGE_FORMATS)
    check_int(quality, "quality", minimum=1, maximum=100)


def viewer_data(views, calibration, *, zmin_m=None, zmax_m=None, num_planes=None, reference="center", depth=None,
                min_confidence: float = 0.5, boxes=None, unchecked_mask=None, image_format: str = "jpeg",
                quality: int = 85, metadata=None, focus_m=None, method: str = "depth-aware", aperture=None,
                f_number=None) -> dict:
    """Everything the page shows, as a JSON-ready dict (images as data: URIs); see :func:`viewer_html`."""
    from lfring import all_in_focus, estimate_depth, focal_stack
    from lfring.depth.io import colorize_depth
    from lfring.focus import METHODS, resolve_aperture
    from lfring.calibration.overlap import check_renderable
    from lfring.focus.depth_aware import DEPTH_AWARE, depth_of_field, estimation_range
    from lfring.io.writers import encode_image

    _check_options(num_planes, min_confidence, image_format, quality)
    m = METHODS.lookup(method)
    # A method with a depth of field renders from the page's depth map at the aperture (resolved
    # here for the metadata); any other refuses those options (focal_stack says which takes them).
    if "aperture" in m.options:
        aperture, f_number_given = resolve_aperture(calibration, aperture, f_number), f_number
        f_number = None
    else:
        f_number_given = None
    box_list = _check_boxes(boxes)
    views = check_views(views)
    calibration.check_fits(views.shape)
    shape_hw = tuple(views.shape[1:3])
    unchecked = None if unchecked_mask is None else _overlay_png(unchecked_mask, shape_hw)
    if depth is not None and num_planes is not None:
        raise InvalidInputError("the stack's planes are the given depth result's hypotheses: give num_planes or depth, not both")
    if depth is not None and zmin_m is None and zmax_m is None:
        zmin_m, zmax_m = float(np.min(depth.depths_m)), float(np.max(depth.depths_m))
    # The page's depth map is what its depth-aware stack renders from: its range follows the
    # rule of depth-aware refocusing everywhere.
    lo, hi = estimation_range(calibration, zmin_m, zmax_m, reference=reference)
    # The stack's nearest frame, before any work (named as the parameter that gave it).
    check_renderable(calibration, lo, reference=reference, name="depth" if zmin_m is None else "zmin_m")
    check_number(focus_m, "focus_m", minimum=lo, maximum=hi, allow_none=True, what="a depth in metres")
    if depth is None:
        depth = estimate_depth(views, calibration, zmin_m=lo, zmax_m=hi, num_planes=num_planes, reference=reference)
    # One stack frame per depth hypothesis (evenly spaced in disparity): a click on any depth
    # the map holds lands on its own frame.
    zs = np.sort(np.asarray(depth.depths_m, dtype=np.float64))
    zs = zs[(zs >= lo - 1e-9) & (zs <= hi + 1e-9)]
    if zs.size < 2:
        raise InvalidInputError(f"the depth result's hypotheses hold fewer than two depths within {lo:g}..{hi:g} m")
    h, w = shape_hw
    depth_m = np.asarray(depth.depth_m, dtype=np.float64)
    conf = np.asarray(depth.confidence, dtype=np.float64)
    if depth_m.shape != (h, w) or conf.shape != (h, w):
        raise InvalidInputError(f"the depth map and confidence must be {h} x {w} (the reference frame), "
                                f"got {depth_m.shape} and {conf.shape}; estimate them with the same reference")
    # The all-in-focus image and a depth-aware stack render from one renderer of the map.
    renderer = depth_of_field(views, calibration, depth=depth, reference=reference)
    # The stack as lfring refocus makes it: depth-aware (by default) from the depth map above.
    options = {"aperture": aperture, "f_number": f_number}
    if "depth" in m.options:  # depth-aware refocusing takes the renderer itself; another method the map
        options["depth"] = renderer if m is DEPTH_AWARE else depth
    stack = focal_stack(views, calibration, zs, reference=reference, method=m.name, **options)
    aif, _ = all_in_focus(views, calibration, depth_map_m=renderer, reference=reference)

    suffix, mime, flag = IMAGE_FORMATS[image_format]
    params = (flag, int(quality))
    frames = [_data_uri(mime, _encode(encode_image(img, 8, "srgb"), suffix, params)) for img in stack]
    known = np.isfinite(depth_m)
    depth_mm = np.zeros((h, w), "<u2")
    depth_mm[known] = np.clip(np.rint(depth_m[known] * 1e3), 1, 65535)
    conf_u8 = np.rint(np.clip(np.nan_to_num(conf, nan=0.0), 0, 1) * 255).astype(np.uint8)
    colour = colorize_depth(depth_m, zmin_m=lo, zmax_m=hi)
    bar_m = np.linspace(lo, hi, COLOUR_BAR_STOPS)
    bar = colorize_depth(bar_m[None, :], zmin_m=lo, zmax_m=hi)[0]

    return {
        "width": int(w), "height": int(h),
        "depths_m": [float(z) for z in zs],
        "depth_origin_m": float(calibration.depth_origin_m),
        "zmin_m": lo, "zmax_m": hi,
        "focus_m": None if focus_m is None else float(focus_m),
        "min_confidence": float(min_confidence),
        "shade_alpha": SHADE_ALPHA,
        "frames": frames,
        "all_in_focus": _data_uri(mime, _encode(encode_image(aif, 8, "srgb"), suffix, params)),
        "depth_colour": _data_uri("image/png", _encode(colour, ".png")),
        "colour_bar": {"depths_m": [float(z) for z in bar_m], "rgb": bar.tolist()},
        "depth_mm_u16le": base64.b64encode(depth_mm.tobytes()).decode("ascii"),
        "confidence_u8": base64.b64encode(conf_u8.tobytes()).decode("ascii"),
        "boxes": box_list,
        "unchecked": unchecked,
        "metadata": {
            "reference": reference,
            "calibration_source": calibration.source,
            "depth_range_m": [lo, hi],
            "stack_planes": len(zs),
            "depth_hypotheses": len(depth.depths_m),
            "depth_step_px": float(depth.step_px),
            "refocus_method": m.name,
            "aperture": aperture,
            **({"f_number": float(f_number_given)} if f_number_given is not None else {}),
            "units": "depth in metres from the main lens (readout in millimetres); confidence in [0, 1]",
            **(metadata or {}),
            "calibration_model": calibration.to_dict(),
        },
    }


def viewer_html(views, calibration, *, zmin_m=None, zmax_m=None, num_planes=None, reference="center", depth=None,
                min_confidence: float = 0.5, boxes=None, unchecked_mask=None, image_format: str = "jpeg",
                quality: int = 85, title: str = "lfring viewer", metadata=None, focus_m=None, method: str = "depth-aware",
                aperture=None, f_number=None) -> str:
    """The viewer of one frame as a self-contained HTML page.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
    calibration : RingCalibration
    zmin_m, zmax_m : float, optional
        Depth range of the focal stack and of the depth sweep [m from the main lens]. Default:
        the range of ``depth``'s hypotheses when given, else depth-aware refocusing's
        (:func:`lfring.focus.depth_aware.estimation_range`: the calibration's valid range,
        or without an upper bound one derived where the calibration allows it).
    num_planes : int, optional
        Depth hypotheses of the sweep, evenly spaced in disparity (default: one pixel of view
        motion apart); the focal stack has a frame at each.
    reference : 'center' or int
    depth : DepthResult, optional
        A depth map already estimated in the same reference frame (default: estimated here
        over the depth range with :func:`lfring.estimate_depth`); the stack then has a frame at
        each of its hypotheses within the depth range (default: all of them).
    min_confidence : float
        Pixels below this confidence are shaded by the low-confidence toggle and skipped when a
        click looks for the depth to focus at.
    boxes : sequence of (x, y, w, h), (x, y, w, h, label) or (x, y, w, h, label, colour), optional
        Rectangles in reference pixels drawn over the image (inspection defects, say), in
        ``colour`` ('#rrggbb'; red by default).
    unchecked_mask : (h, w) bool, optional
        Area drawn as an overlay (the area an inspection could not check, say).
    image_format : {'jpeg', 'webp'}
        Encoding of the focal stack and the all-in-focus image (8-bit sRGB).
    quality : int
        Encoder quality, 1-100.
    title : str
    focus_m : float, optional
        Depth the page opens focused at (its nearest frame); default: the middle of the range.
    metadata : dict, optional
        JSON-ready entries shown in the page's metadata panel (input file, calibration name...);
        the panel also says which method and aperture made the focal stack.
    method : str
        The refocusing method of the focal stack (:func:`lfring.refocus`): 'depth-aware' (the
        default, as ``lfring refocus``'s) renders every frame from the depth map above as a lens
        of ``aperture`` would; 'shift-and-add' averages the views (out-of-focus objects as
        copies).
    aperture, f_number : float, optional
        'depth-aware': the lens's aperture (1, the default: the one the views span), or the
        main lens's f-number instead (:func:`lfring.focus.resolve_aperture`).

    Returns
    -------
    str
        The HTML page; it loads nothing from the network (its Content-Security-Policy forbids it).
    """
    check_calibration(calibration)
    from lfring.io.writers import json_default

    data = viewer_data(views, calibration, zmin_m=zmin_m, zmax_m=zmax_m, num_planes=num_planes, reference=reference,
                       depth=depth, min_confidence=min_confidence, boxes=boxes, unchecked_mask=unchecked_mask,
                       image_format=image_format, quality=quality, metadata=metadata, focus_m=focus_m, method=method,
                       aperture=aperture, f_number=f_number)
    # "<" escaped so that no string in the data can close the script element.
    payload = json.dumps(data, separators=(",", ":"), default=json_default).replace("<", "\\u003c")
    return _template().replace("__LF_TITLE__", html.escape(str(title))).replace("__LF_DATA__", payload)


def inspection_overlays(result) -> dict:
    """Keywords of :func:`viewer_html` for an :class:`lfring.InspectionResult`: its defect boxes
    (labelled with kind and deviation), the area it could not check (pixels that cannot raise an
    alarm), its depth map, the depth band it searched and, as the first focus, the working plane.

    Examples
    --------
    ``write_viewer("part_viewer.html", views, calibration, **inspection_overlays(result))``
    """
    from lfring.inspect.draw import BUMP_RGB, DENT_RGB

    hexed = {kind: "#%02x%02x%02x" % rgb for kind, rgb in (("bump", BUMP_RGB), ("dent", DENT_RGB))}
    boxes = [(*d.bbox_px, f"{i} {d.kind} {d.deviation_m * 1e3:+.1f} mm", hexed.get(d.kind, BOX_COLOUR))
             for i, d in enumerate(result.defects, 1)]
    zs = np.asarray(result.depth.depths_m, dtype=np.float64)
    return {"boxes": boxes, "unchecked_mask": result.unchecked, "depth": result.depth,
            "zmin_m": float(zs.min()), "zmax_m": float(zs.max()), "focus_m": float(result.settings["plane_m"])}


def write_viewer(path, views, calibration, *, overwrite: bool = False, **options) -> Path:
    """Write :func:`viewer_html`'s page to ``path`` (atomically); ``options`` are its keywords.

    Refuses to replace an existing file unless ``overwrite``. Returns the path.
    """
    from lfring.io.atomic import atomic_write_text
    from lfring.io.writers import check_writable

    path = Path(path)
    check_writable([path], overwrite=overwrite)
    page = viewer_html(views, calibration, **options)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, page)
