"""How much of the (pixel, hypothesis) cost volume a real scene needs: the bound on a sweep that
searches each tile only around the depths found there (coarse to fine, as tSGM does).

For Middlebury 2003 Teddy and Cones (``bench_depth_real.middlebury``: disparities 1 to 60 px),
the share of the volume that tiles of 16 or 32 px would search, each over a range of disparities
widened by a margin (in planes, one a pixel of disparity):

- from the ground truth (each tile's 1st to 99th percentile of true disparity): the bound;
- from a first pass: the default ``estimate_depth`` on the pair shrunk to half size (its filled
  map, scaled to full resolution), each tile's least to largest disparity; beside it, the share
  of the ground-truth pixels whose disparity falls outside their tile's range (a finer pass
  over those ranges could not find them).

    python benchmarks/bench_volume_share.py
    python benchmarks/bench_volume_share.py --data /work/shared/data/middlebury2003
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import cv2
import numpy as np
from bench_depth_real import DATA, DISPARITY_RANGE_PX, DISPARITY_SCALE_PX_M, make_data, middlebury

from lfring.calibration import RingCalibration
from lfring.depth import estimate_depth

CASES = ((16, 3), (32, 3), (16, 6), (32, 6))  # (tile px, margin in planes)


def tile_ranges(disparity, tile: int, margin: int, percentiles=None):
    """Per tile of ``disparity`` (NaN where unknown): the range (lo, hi) of disparities it would
    search, from its least and largest values (or the given percentiles), widened by ``margin``
    and clipped to the search range; the whole range where the tile has no value."""
    lo0, hi0 = DISPARITY_RANGE_PX
    h, w = disparity.shape
    for y in range(0, h, tile):
        for x in range(0, w, tile):
            t = disparity[y:y + tile, x:x + tile]
            known = t[np.isfinite(t)]
            if known.size == 0:
                yield (y, x), (lo0, hi0)
                continue
            a, b = (np.percentile(known, percentiles) if percentiles else (known.min(), known.max()))
            yield (y, x), (max(lo0, np.floor(a) - margin), min(hi0, np.ceil(b) + margin))


def share(disparity, truth, tile: int, margin: int, percentiles=None) -> tuple[float, float]:
    """(share of the volume searched, share of the known true disparities outside their tile's range)."""
    lo0, hi0 = DISPARITY_RANGE_PX
    planes = hi0 - lo0 + 1
    searched = missed = known = 0
    for (y, x), (lo, hi) in tile_ranges(disparity, tile, margin, percentiles):
        t = truth[y:y + tile, x:x + tile]
        searched += (hi - lo + 1) * t.size
        g = t[np.isfinite(t)]
        known += g.size
        missed += np.count_nonzero((g < lo) | (g > hi))
    return searched / (planes * truth.size), missed / max(known, 1)


def first_pass(views) -> np.ndarray:
    """The default estimate on the pair at half size, as disparity in full-resolution px."""
    h, w = views.shape[1:3]
    half = np.stack([cv2.resize(v, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for v in views[:2]])
    cal = RingCalibration.from_grid(half.shape[1:3], [(0, 0), (1, 0)], disparity_scale_px_m=DISPARITY_SCALE_PX_M / 2)
    data = make_data("half", half, cal, disparity_range_px=tuple(d / 2 for d in DISPARITY_RANGE_PX))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = estimate_depth(half, cal, zmin_m=data.zmin_m, zmax_m=data.zmax_m)
    disparity = data.disparity(result.depth_filled_m) * 2.0
    return cv2.resize(disparity, (w, h), interpolation=cv2.INTER_NEAREST)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="the folder with Teddy/ and Cones/")
    args = ap.parse_args()
    print("| scene | tiles px | margin planes | share, ranges from the truth | share, ranges from a half-size pass "
          "| true disparities outside their range |")
    print("|---|---|---|---|---|---|")
    for scene in ("Teddy", "Cones"):
        data = middlebury(scene, args.data)
        truth = data.gt_disparity
        found = first_pass(data.views)
        for tile, margin in CASES:
            bound, _ = share(truth, truth, tile, margin, percentiles=(1, 99))
            searched, missed = share(found, truth, tile, margin)
            print(f"| {scene} | {tile} | {margin} | {bound:.2f} | {searched:.2f} | {100 * missed:.1f} % |")


if __name__ == "__main__":
    main()
