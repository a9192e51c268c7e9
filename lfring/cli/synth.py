"""``lfring synth``: render frames of the synthetic twin, with their ground truth."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import click
import numpy as np

from lfring.cli._options import device_option, get_device
from lfring.io.bayer import PATTERNS

log = logging.getLogger("lfring.cli.synth")


def _parse_defects(text: str) -> tuple[float, ...]:
    if text.strip().lower() == "none":
        return ()
    try:
        heights = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected 'none' or comma-separated heights in metres, got {text!r}") from None
    if any(not np.isfinite(h) or h == 0 for h in heights):
        raise click.BadParameter(f"defect heights must be non-zero finite metres, got {text!r}")
    return heights


@click.command("synth")
@click.argument("preset", type=click.Choice(["flat", "target", "scene", "part", "file"]))
@click.option("-o", "--output", "outdir", type=click.Path(file_okay=False), required=True, metavar="DIR",
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
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of textures, defect placement and noise.")
@click.option("--format", "fmt", type=click.Choice(["png", "tiff"]), default="png", show_default=True,
              help="Raw frame file format.")
@click.option("--name", default=None, help="Base name of the output files (default from the preset).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
def command(preset, outdir, depth, scene_file, defects, defect_size, part_depth, device_name, binning, pattern,
            bit_depth, noise, gain, exposure, rotate180, seed, fmt, name, overwrite):
    """Render a raw frame of the synthetic twin and its ground truth.

    PRESET is 'flat' (white field), 'target' (speckle target at --depth), 'scene' (cup at 0.3 m,
    book at 0.5 m, chessboard at 1.0 m, slanted floor), 'part' (inspection part with --defects)
    or 'file' (--scene FILE). Writes DIR/NAME.png (or .tiff), its sidecar DIR/NAME.png.json
    (pattern and levels, read back by lfring's loader) and DIR/NAME_truth/ (per-view depth in
    metres as float32 TIFF, layout.json, truth.json with settings, b, c and the exact homographies).
    """
    from lfring.synth import presets
    from lfring.synth.renderer import RenderSettings, render

    device = get_device(device_name)
    if preset == "target" and depth is None:
        raise click.UsageError("preset 'target' needs --depth M")
    if preset != "target" and depth is not None:
        raise click.UsageError("--depth is for preset 'target'")
    if (preset == "file") != (scene_file is not None):
        raise click.UsageError("--scene FILE goes with preset 'file' (and only with it)")
    settings = RenderSettings(
        binning=binning, pattern=None if pattern.lower() == "none" else pattern.upper(), bit_depth=int(bit_depth),
        noise=noise, gain=gain, exposure=exposure, rotate180=rotate180, seed=seed,
    )
    if preset == "flat":
        scene, default_name = presets.flat_scene(device), "flat"
    elif preset == "target":
        scene, default_name = presets.target_scene(device, depth, seed=seed), f"target_{depth:g}m"
    elif preset == "scene":
        scene, default_name = presets.three_depth_scene(), "scene"
    elif preset == "part":
        heights = _parse_defects(defects)
        scene = presets.part_scene(defect_heights_m=heights, defect_size_m=defect_size, depth_m=part_depth, seed=seed)
        default_name = "part_good" if not heights else "part_defects"
    else:
        scene = presets.load_scene(scene_file)
        default_name = Path(scene_file).stem
    name = name or default_name
    out = Path(outdir)
    raw_path = out / f"{name}.{'png' if fmt == 'png' else 'tiff'}"
    written = write_render(render(device, scene, settings), raw_path, preset=preset, overwrite=overwrite)
    for p in written:
        log.info("wrote %s", p)
    click.echo(str(raw_path))


def write_render(result, raw_path: Path, *, preset: str = "", overwrite: bool = False) -> list[Path]:
    """Write a :class:`~lfring.synth.RenderResult`: raw frame, sidecar and ground-truth folder."""
    from lfring.io.raw import sidecar_path
    from lfring.io.writers import check_writable, write_float_tiff, write_image, write_json
    from lfring.optics.views import optical_homography_model

    raw_path = Path(raw_path)
    truth = raw_path.with_name(raw_path.stem + "_truth")
    side = sidecar_path(raw_path)
    depth_paths = [truth / f"depth_view{k}.tiff" for k in range(result.layout.num_views)]
    layout_path = truth / "layout.json"
    check_writable([raw_path, side, truth / "truth.json", layout_path, *depth_paths], overwrite=overwrite)
    meta = result.metadata()
    surfaces = []
    for s in result.scene.surfaces:
        d = dataclasses.asdict(s)
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
    truth.mkdir(exist_ok=True)
    for k, p in enumerate(depth_paths):
        write_float_tiff(p, result.depth_m[k])
    write_json(truth / "truth.json", truth_doc)
    result.layout.save(layout_path)
    return [raw_path, side, *depth_paths, truth / "truth.json", layout_path]
