"""Reading an animated GIF back in the tests (Pillow, which lfring writes GIFs with)."""

import numpy as np
from PIL import Image, ImageSequence


def read_gif(path) -> np.ndarray:
    """The frames of a GIF as (N, H, W, 3) uint8."""
    with Image.open(path) as im:
        return np.stack([np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(im)])
