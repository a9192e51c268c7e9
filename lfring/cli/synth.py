"""``lfring synth``: render frames of the synthetic twin, with their ground truth."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import device_option, get_device, output_folder
from lfring.cli.words import cli_words
from lfring.errors import InvalidInputError
from lfring.io.bayer import PATTERNS

log = logging.getLogger("lfring.cli.synth")

#: The library's names of the values this command checks, and the options that give them.
_OPTIONS = {
    "binning": "--binning",
    "gain": "--gain",
    "exposure": "--exposure",
    "target depth": "--depth",
    "defect size": "--defect-size",
    "part depth_m": "--part-depth",
    "focus_m": "--conventional-focus",
    "f_number": "--f-number",
    "aperture_scale": "--aperture-scale",
    "samples": "--conventional-samples",
}

#: The library's phrases about a part, and the options they are about.
_PART_WORDS = (
    ("not small against the part distance", "not small against the part distance (--part-depth {part_depth:g} m)"),
    ("give fewer or smaller defects", "give fewer --defects or a smaller --defect-size"),
)

#: A defect's size or height typed as this many metres or more is most likely millimetres:
#: a refusal then says so.
_MILLIMETRES_FROM_M = 1.0


@contextlib.contextmanager
def _as_options(default: str | None = None):
    """Turn a refusal of the library inside the block into a usage error that names the option
    (:data:`_OPTIONS`, from the name the message starts with; else ``default``; with neither,
    the refusal goes on as it is)."""
    try:
        yield
    except InvalidInputError as exc:
        message = str(exc)
        name = next((n for n in _OPTIONS if message.startswith(n + " ")), None)
        option = _OPTIONS[name] if name else default
        if option is None:
            raise
        if name and message.startswith(f"{name} must be"):
            message = message[len(name) + 1:]
        message = cli_words(message)
        for phrase, words in _PART_WORDS:
            message = message.replace(phrase, words.format(**click.get_current_context().params))
        raise click.BadParameter(message + _millimetres_hint(option), param_hint=option) from None


def _millimetres_hint(option: str) -> str:
    """For a defect option given in the command line as metres large enough to be millimetres:
    a hint that says the unit, with the value in metres."""
    if option not in ("--defects", "--defect-size"):
        return ""
    ctx = click.get_current_context()
    values = ctx.params["defects" if option == "--defects" else "defect_size"]
    values = _parse_defects(values) if option == "--defects" else (values,)
    if not any(abs(v) >= _MILLIMETRES_FROM_M for v in values):
        return ""
    given = ",".join(f"{v:g}" for v in values)
    metres = ",".join(f"{v / 1000:g}" for v in values)
    return f" (the option is in metres: for {given} mm give {option} {metres})"


def _parse_defects(text: str) -> tuple[float, ...]:
    if text.strip().lower() == "none":
        return ()
    try:
        heights = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected 'none' or comma-separated heights in metres, got {text!r}",
                                 param_hint="--defects") from None
    if any(not np.isfinite(h) or h == 0 for h in heights):
        raise click.BadParameter(f"defect heights must be non-zero finite metres, got {text!r}", param_hint="--defects")
    return heights


@click.command("synth")
@click.argument("preset", type=click.Choice(["flat", "target", "scene", "part", "hard", "file"]))
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, callback=output_folder, metavar="DIR",
              help="Output folder (created if missing).")
@click.option("--depth", type=float, default=None, metavar="M", help="Target distance [m] (preset 'target').")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="TOML scene file (preset 'file').")
@click.option("--defects", default="0.015,-0.015", show_default=True, metavar="none|H1,H2,...",
              help="Preset 'part': heights of planted defects [m], + towards the camera (bump), - away (dent).")
@click.option("--defect-size", type=float, default=0.012, show_default=True, metavar="M", help="Defect diameter [m].")
@click.option("--part-depth", type=float, default=0.3, show_default=True, metavar="M", help="Part distance [m].")
@device_option
@click.option("--binning", type=int, default=2, show_default=True, help="Sensor binning factor (1 = full resolution).")
@click.option("--pattern", type=click.Choice([*PATTERNS, "none"], case_sensitive=False), default="RGGB",
              show_default=True, help="Bayer pattern of the raw frame, or 'none' for RGB.")
@click.option("--bit-depth", type=click.Choice(["8", "12", "16"]), default="12", show_default=True, help="Bits per sample.")
@click.option("--noise", type=click.Choice(["none", "low", "realistic", "high"]), default="realistic", show_default=True,
              help="Sensor noise preset (shot + read noise).")
@click.option("--gain", type=float, default=1.0, show_default=True, help="Analogue gain (unitless).")
@click.option("--exposure", type=float, default=0.8, show_default=True,
              help="Fraction of full scale reached by a white, unvignetted surface.")
@click.option("--rotate180", is_flag=True, help="Write the frame rotated by 180 degrees, as the paper's camera does.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the noise, and of the textures of 'target' and 'part' and the placement of "
                   "the part's defects ('scene' and 'hard' are fixed scenes; a 'file' scene's textures carry their own seeds).")
@click.option("--format", "fmt", type=click.Choice(["png", "tiff"]), default="png", show_default=True,
              help="Raw frame file format.")
@click.option("--conventional-focus", "conventional_focus", type=float, multiple=True, metavar="M",
              help="Also write the conventional image focused at M metres (repeatable): ground truth for refocusing, "
                   "in the views' 'center' frame, to NAME_truth/conventional_<M>m.tiff (float32 linear RGB) and .png.")
@click.option("--f-number", type=float, default=None, metavar="N",
              help="Conventional image: the main lens's aperture at f-number N (default its full aperture).")
@click.option("--aperture-scale", type=float, default=None, metavar="A",
              help="Conventional image: an aperture A times the radius the four viewpoints span (1: the views' span).")
@click.option("--conventional-samples", type=int, default=None, metavar="N",
              help="Conventional image: aperture samples (default: about one per 2 px of the largest blur).")
@click.option("--name", default=None, help="Base name of the output files (default from the preset).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
def command(preset, outdir, depth, scene_file, defects, defect_size, part_depth, device_name, binning, pattern,
            bit_depth, noise, gain, exposure, rotate180, seed, fmt, conventional_focus, f_number, aperture_scale,
            conventional_samples, name, overwrite):
    """Render a raw frame of the synthetic twin and its ground truth.

    PRESET is 'flat' (white field), 'target' (speckle target at --depth), 'scene' (cup at 0.3 m,
    book at 0.5 m, chessboard at 1.0 m, slanted floor), 'part' (inspection part with --defects),
    'hard' (thin wires, slanted, curved and textureless surfaces, edges at every orientation,
    vignetting that differs per view) or 'file' (--scene FILE). Writes DIR/NAME.png (or .tiff), its sidecar DIR/NAME.png.json
    (pattern and levels, read back by lfring's loader) and DIR/NAME_truth/ (per-view depth in
    metres as float32 TIFF, layout.json, truth.json with settings, b, c and the exact homographies).
    With --conventional-focus, NAME_truth/ also gets the conventional image at that focus
    (conventional_<M>m[_f<N>|_a<A>].tiff, .png preview in sRGB, .json with the aperture).
    """
    from lfring.synth import presets
    from lfring.synth import RenderSettings, render

    device = get_device(device_name)
    if not device.has_positions:
        raise click.BadParameter(f"device '{device.name}' has no lens positions to render with: add its ring_distance_m "
                                 "and sensor_distance_m (b and c; lfring design --device ... --object-size M --distance M "
                                 "prints them for a field of view)", param_hint="--device")
    if preset == "target" and depth is None:
        raise click.UsageError("preset 'target' needs --depth M")
    if preset != "target" and depth is not None:
        raise click.UsageError("--depth is for preset 'target'")
    if (preset == "file") != (scene_file is not None):
        raise click.UsageError("--scene FILE goes with preset 'file' (and only with it)")
    if not conventional_focus and (f_number is not None or aperture_scale is not None or conventional_samples is not None):
        raise click.UsageError("--f-number, --aperture-scale and --conventional-samples go with --conventional-focus")
    if f_number is not None and aperture_scale is not None:
        raise click.UsageError("give --f-number or --aperture-scale, not both")
    # Every value is checked here, before the rendering, and a refusal names its option.
    with _as_options():
        settings = RenderSettings(
            binning=binning, pattern=None if pattern.lower() == "none" else pattern.upper(), bit_depth=int(bit_depth),
            noise=noise, gain=gain, exposure=exposure, rotate180=rotate180, seed=seed,
        )
    if preset == "flat":
        scene, default_name = presets.flat_scene(device), "flat"
    elif preset == "target":
        with _as_options("--depth"):
            scene, default_name = presets.target_scene(device, depth, seed=seed), f"target_{depth:g}m"
    elif preset == "scene":
        scene, default_name = presets.three_depth_scene(), "scene"
    elif preset == "hard":
        scene, default_name = presets.hard_scene(), "hard"
        settings = dataclasses.replace(settings, view_falloff=presets.HARD_VIEW_FALLOFF)
    elif preset == "part":
        heights = _parse_defects(defects)
        with _as_options("--defects"):
            scene = presets.part_scene(defect_heights_m=heights, defect_size_m=defect_size, depth_m=part_depth,
                                       seed=seed)
        default_name = "part_good" if not heights else "part_defects"
    else:
        scene = presets.load_scene(scene_file)
        default_name = Path(scene_file).stem
    if conventional_focus:
        from lfring.synth.conventional import check_conventional

        binned = device.binned(binning)
        for z in conventional_focus:
            with _as_options():
                check_conventional(binned, z, f_number=f_number, aperture_scale=aperture_scale,
                                   samples=conventional_samples)
    name = name or default_name
    out = Path(outdir)
    raw_path = out / f"{name}.{'png' if fmt == 'png' else 'tiff'}"
    conv_paths = [conventional_paths(raw_path, z, f_number=f_number, aperture_scale=aperture_scale)
                  for z in conventional_focus]
    from lfring.cli.outputs import OutputSet
    from lfring.optics.views import optical_layout

    # The outputs are checked before the rendering (which takes a while): a refusal comes first.
    views = optical_layout(device.binned(binning)).num_views
    outputs = OutputSet([*render_paths(raw_path, views), *(p for paths in conv_paths for p in paths)], name=name,
                        overwrite=overwrite)
    outputs.check()
    result = render(device, scene, settings)
    with outputs.writing() as stage:
        write_render(result, stage(raw_path), preset=preset, overwrite=True)
        for z, paths in zip(conventional_focus, conv_paths):
            write_conventional(scene, device, z, [stage(p) for p in paths], binning=binning, f_number=f_number,
                               aperture_scale=aperture_scale, samples=conventional_samples)
    for p in outputs.paths:
        log.info("wrote %s", p)
    click.echo(str(raw_path))


def render_paths(raw_path: Path, num_views: int) -> list[Path]:
    """The files :func:`write_render` writes for a render of ``num_views`` views at
    ``raw_path``: the raw frame, its sidecar, and the ground-truth folder's depth maps,
    truth.json and layout.json."""
    from lfring.io.raw import sidecar_path

    raw_path = Path(raw_path)
    truth = raw_path.with_name(raw_path.stem + "_truth")
    return [raw_path, sidecar_path(raw_path), *(truth / f"depth_view{k}.tiff" for k in range(num_views)),
            truth / "truth.json", truth / "layout.json"]


def write_render(result, raw_path: Path, *, preset: str = "", overwrite: bool = False) -> list[Path]:
    """Write a :class:`~lfring.synth.RenderResult`: raw frame, sidecar and ground-truth folder."""
    from lfring.io.writers import check_writable, write_float_tiff, write_image, write_json
    from lfring.optics.views import optical_homography_model

    raw_path = Path(raw_path)
    paths = render_paths(raw_path, result.layout.num_views)
    _, side, *depth_paths, truth_path, layout_path = paths
    check_writable(paths, overwrite=overwrite)
    meta = result.metadata()
    surfaces = []
    for s in result.scene.surfaces:
        d = dataclasses.asdict(s)
        if d.get("roll_deg", None) == 0.0:  # a field added later: frames without it stay as they were
            del d["roll_deg"]
        d["type"] = type(s).__name__
        surfaces.append(d)
    models = {}
    for ref in ("center", 0):
        a, b, z0 = optical_homography_model(result.device, result.layout, reference=ref)
        models[str(ref)] = {"A": a, "B": b, "depth_origin_m": z0}
    planes = sorted({round(s.depth_m, 9) for s in result.scene.surfaces})
    side_doc = {
        "pattern": result.settings.pattern,
        "black_level": result.black_level,
        "white_level": result.white_level,
        "bit_depth": result.settings.bit_depth,
        "source": f"lfring synth {preset}".strip(),
    }
    truth_doc = {
        **meta,
        "preset": preset,
        "scene": {"name": result.scene.name, "background": result.scene.background, "surfaces": surfaces},
        "homography_model": {
            "form": "H_ref_from_view(Z) = A + B / (Z - depth_origin_m), Z in metres from the main lens",
            "references": models,
        },
        "H_center_from_view_at_surface_depths": {f"{z:g}": result.homographies(z) for z in planes},
        "depth_files": [p.name for p in depth_paths],
        "depth_units": "metres from the main lens; NaN where no surface is seen",
    }
    raw_path.parent.mkdir(parents=True, exist_ok=True)
    write_image(raw_path, result.raw, png_compression=3)  # raw frames are kept: smaller files
    write_json(side, side_doc)
    truth_path.parent.mkdir(exist_ok=True)
    for k, p in enumerate(depth_paths):
        write_float_tiff(p, result.depth_m[k])
    write_json(truth_path, truth_doc)
    result.layout.save(layout_path)
    return paths


def conventional_paths(raw_path: Path, focus_m: float, *, f_number=None, aperture_scale=None) -> tuple[Path, Path, Path]:
    """TIFF, PNG preview and JSON of the conventional image at ``focus_m`` beside the frame's
    ground truth: ``NAME_truth/conventional_<Z>m[_f<N>|_a<A>]``."""
    raw_path = Path(raw_path)
    stem = f"conventional_{focus_m:g}m"
    if f_number is not None:
        stem += f"_f{f_number:g}"
    elif aperture_scale is not None:
        stem += f"_a{aperture_scale:g}"
    truth = raw_path.with_name(raw_path.stem + "_truth")
    return truth / f"{stem}.tiff", truth / f"{stem}.png", truth / f"{stem}.json"


def write_conventional(scene, device, focus_m: float, paths, *, binning: int, f_number=None, aperture_scale=None,
                       samples=None) -> list[Path]:
    """Render :func:`lfring.synth.render_conventional` and write it: float32 RGB TIFF (linear
    radiance), 8-bit sRGB PNG preview, and JSON describing the aperture and frame."""
    import tifffile

    from lfring.io.atomic import atomic_path
    from lfring.io.writers import encode_image, write_image, write_json
    from lfring.optics.views import view_cameras
    from lfring.synth import (
        conventional_aperture_radius_m,
        conventional_sample_count,
        render_conventional,
        viewpoint_radius_m,
    )

    tiff_path, png_path, json_path = paths
    dev = device.binned(binning)
    radius = conventional_aperture_radius_m(dev, f_number=f_number, aperture_scale=aperture_scale)
    n = samples if samples is not None else conventional_sample_count(scene, dev, focus_m, radius)
    image = render_conventional(scene, device, focus_m, f_number=f_number, aperture_scale=aperture_scale,
                                samples=n if radius > 0 else None, binning=binning)
    tiff_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(tiff_path) as tmp:
        tifffile.imwrite(tmp, image, photometric="rgb", compression="zlib")
    write_image(png_path, encode_image(image, 8, "srgb"))
    cams = view_cameras(dev)
    write_json(json_path, {
        "focus_m": focus_m,
        "f_number": f_number,
        "aperture_scale": aperture_scale,
        "aperture_radius_m": radius,
        "aperture_plane_m": cams.depth_origin_m,
        "viewpoint_radius_m": viewpoint_radius_m(dev),
        "samples": 1 if radius == 0 else int(n),
        "reference": "center",
        "shape": list(image.shape),
        "units": "linear RGB radiance in [0, 1]; not scaled by the exposure, no noise, no vignetting",
        "blur_diameter_px": "2 aperture_radius_m f |1/(focus_m - s) - 1/(Z - s)| / pixel pitch, "
                            "s = aperture_plane_m, f = views' focal length",
        "focal_m": cams.focal_m,
        "pixel_pitch_m": dev.pixel_pitch_m,
    })
    return [tiff_path, png_path, json_path]
