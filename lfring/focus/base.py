"""The record of one refocusing method."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["RefocusMethod"]


@dataclass(frozen=True)
class RefocusMethod:
    """One refocusing method (the ``method`` of :func:`lfring.refocus`).

    Every method starts from the shift-and-add image at the focus depth (the views aligned
    there and averaged: in focus, what the lens records); a method that renders the rest
    differently prepares, once per frame, a function that finishes that image.

    Attributes
    ----------
    name : str
    summary : str
        One line for help texts.
    prepare : callable or None
        ``prepare(views, calibration, reference, **options)`` -> ``finish(sharp, depth_m)`` ->
        image, made once for a frame and reused for every focus depth; None when the
        shift-and-add image is the result.
    backends : tuple of str
        The backends it runs on.
    options : frozenset of str
        The method-specific keyword options of :func:`lfring.refocus` it takes.
    """

    name: str
    summary: str
    prepare: Callable | None
    backends: tuple = ("numpy",)
    options: frozenset = frozenset()
