"""The synthetic twin of the ring camera: scenes, textures and the renderer (SPEC 3)."""

from lfring.synth.renderer import (
    NOISE_PRESETS,
    RenderResult,
    RenderSettings,
    aperture_samples,
    conventional_aperture_radius_m,
    conventional_blur_px,
    conventional_sample_count,
    render,
    render_conventional,
    view_falloff_map,
    viewpoint_radius_m,
)
from lfring.synth.scene import Bump, HeightField, Plane, Scene
from lfring.synth.textures import IMAGES, Texture

__all__ = [
    "IMAGES",
    "NOISE_PRESETS",
    "Bump",
    "HeightField",
    "Plane",
    "RenderResult",
    "RenderSettings",
    "Scene",
    "Texture",
    "aperture_samples",
    "conventional_aperture_radius_m",
    "conventional_blur_px",
    "conventional_sample_count",
    "render",
    "render_conventional",
    "view_falloff_map",
    "viewpoint_radius_m",
]
