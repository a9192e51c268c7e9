"""Optics of the ring camera: device records, the paraxial model, design and ray tracing."""

from lfring.optics.design import (
    METHODS,
    Design,
    Sweep,
    WorkingRange,
    design,
    design_working_range,
    evaluate,
    sweep,
)
from lfring.optics.device import RingDevice, builtin_devices, load_device, save_device

__all__ = [
    "METHODS",
    "Design",
    "RingDevice",
    "Sweep",
    "WorkingRange",
    "builtin_devices",
    "design",
    "design_working_range",
    "evaluate",
    "load_device",
    "save_device",
    "sweep",
]
