"""The synthetic twin of the ring camera: scenes, textures, the raw-frame renderer with its sensor
model, and the conventional image that is the ground truth for refocusing."""

from lfring.synth.conventional import (
    aperture_samples,
    conventional_aperture_radius_m,
    conventional_blur_px,
    conventional_sample_count,
    render_conventional,
    viewpoint_radius_m,
)
from lfring.synth.renderer import render, view_falloff_map
from lfring.synth.result import RenderResult
from lfring.synth.scene import Bump, HeightField, Plane, Scene
from lfring.synth.settings import NOISE_PRESETS, RenderSettings
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
