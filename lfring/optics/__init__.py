"""Optics of the ring camera: device records, the paraxial model, design and ray tracing."""

from lfring.optics.positions import (
    METHODS,
    Design,
    Sweep,
    WorkingRange,
    design,
    design_working_range,
    evaluate,
    sweep,
)
from lfring.optics.device import MiniLens, RingDevice, builtin_devices, load_device, save_device
from lfring.optics.raytrace import RayTrace, bundle_stats, trace

__all__ = [
    "METHODS",
    "Design",
    "MiniLens",
    "RayTrace",
    "RingDevice",
    "Sweep",
    "WorkingRange",
    "builtin_devices",
    "bundle_stats",
    "design",
    "design_working_range",
    "evaluate",
    "load_device",
    "save_device",
    "sweep",
    "trace",
]
