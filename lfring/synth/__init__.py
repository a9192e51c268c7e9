"""The synthetic twin of the ring camera: scenes, textures and the renderer (SPEC 3)."""

from lfring.synth.renderer import NOISE_PRESETS, RenderResult, RenderSettings, render
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
    "render",
]
