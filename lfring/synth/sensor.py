"""The twin's sensor: the colour filter array, shot and read noise, and quantisation that turn
the linear image on the sensor into raw counts."""

from __future__ import annotations

import time

import numpy as np

from lfring.io.bayer import mosaic
from lfring.synth.settings import NOISE_PRESETS, RenderSettings

__all__ = ["draw_noise", "raw_counts"]


def draw_noise(shape: tuple[int, ...], settings: RenderSettings) -> tuple[np.ndarray, float]:
    """Standard normal float32 noise of the frame from the settings' seed, and the seconds it took."""
    t = time.perf_counter()
    noise = np.random.default_rng(settings.seed).standard_normal(shape, dtype=np.float32)
    return noise, time.perf_counter() - t


def raw_counts(image: np.ndarray, settings: RenderSettings, *, noise: np.ndarray | None = None, pool=None,
               stripes: int = 1) -> np.ndarray:
    """Colour filter, shot and read noise, and quantisation of a [0, 1] linear image.

    Parameters
    ----------
    image : (H, W, 3) float32 ndarray
        Linear radiance on the sensor, exposed, in [0, 1].
    settings : RenderSettings
        Pattern, noise preset and gain, bit depth and black level.
    noise : ndarray, optional
        The frame's standard normal draw (:func:`draw_noise`), drawn here when not given; it is
        used up (scaled in place).
    pool : concurrent.futures.Executor, optional
        Runs ``stripes`` bands of rows on its threads.

    Returns
    -------
    ndarray
        (H, W) Bayer mosaic, or (H, W, 3) without a pattern; uint8 at 8 bits, else uint16.
    """
    pattern = settings.pattern
    shape = image.shape[:2] if pattern else image.shape
    black, white = settings.effective_black_level, settings.white_level
    span = white - black
    preset = NOISE_PRESETS[settings.noise]
    if preset is not None and noise is None:
        noise = draw_noise(shape, settings)[0]
    out = np.empty(shape, np.uint8 if settings.bit_depth == 8 else np.uint16)

    def stripe(rows: slice) -> None:
        signal = mosaic(image[rows], pattern) if pattern else image[rows].copy()
        if preset is not None:
            full_well, read = preset
            e_full = full_well / settings.gain  # electrons at full scale
            e = signal
            e *= np.float32(e_full)
            sd = e + np.float32(read * read)
            np.sqrt(sd, out=sd)
            n = noise[rows]
            n *= sd
            e += n
            e *= np.float32(1.0 / e_full)
        counts = signal
        counts *= np.float32(span)
        counts += np.float32(black)
        np.rint(counts, out=counts)
        np.clip(counts, 0, white, out=counts)
        np.copyto(out[rows], counts, casting="unsafe")

    # Stripes start on even rows, so every stripe sees the Bayer pattern in its own phase.
    n = 1 if pool is None else max(1, stripes)
    cuts = sorted({0, shape[0]} | {2 * ((shape[0] * i // n) // 2) for i in range(1, n)})
    rows = [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    if pool is None:
        for r in rows:
            stripe(r)
    else:
        list(pool.map(stripe, rows))
    return out
