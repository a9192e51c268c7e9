"""Does the confidence rank the errors? Sparsification curves of estimate_depth's depth error
against its confidence, on real pairs (Middlebury 2003 Teddy and Cones) and the twin's scenes.

    python benchmarks/bench_confidence.py

For each dataset and method: the mean absolute disparity error (px; the twin: between views 0
and 1) of the most confident fraction of the pixels, averaged over fractions 5 %, 10 %, ..., 100 %
(the area under the sparsification curve, AUC; lower is better), beside the oracle's (pixels
ranked by their true error: the best any confidence could do) and the random ranking's (the
mean error). Pixels: every pixel with ground truth (Middlebury: 10 px from the border; the
twin: seen by two views or more); a pixel without an estimate counts with the error of the
Middlebury SDK's fill and confidence 0.
"""

from __future__ import annotations

import warnings

import numpy as np
from _common import fill_invalid, machine_line

import bench_depth_real as real
from lfring.depth import estimate_depth
from lfring.depth.sgm import sparsification_auc
from lfring.errors import LfringWarning


def main() -> None:
    print(machine_line())
    print("| data | method | views | pixels | AUC px | oracle AUC px | random AUC px | AUC / random |")
    print("|---|---|---|---|---|---|---|---|")
    datasets = [real.middlebury(s) for s in real.SCENES] + [real.twin(), real.twin("hard"), real.twin("hard_mirrored")]
    for data in datasets:
        region = next(iter(data.regions.values()))
        for method in ("sgm", "local"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LfringWarning)
                res = estimate_depth(data.views, data.cal, zmin_m=data.zmin_m, zmax_m=data.zmax_m, reference=0, method=method)
            disparity = fill_invalid(data.disparity(res.depth_m), far_is_lower=data.far_is_lower)
            error = np.where(region, np.abs(disparity - data.gt_disparity), np.nan)
            confidence = np.where(np.isfinite(res.depth_m), res.confidence, 0.0)
            s = sparsification_auc(error, confidence)
            print(f"| {data.name} | {method} | {data.views.shape[0]} | {int(np.isfinite(error).sum())} | {s.auc:.3f} | "
                  f"{s.oracle_auc:.3f} | {s.random_auc:.3f} | {s.auc / s.random_auc:.2f} |", flush=True)


if __name__ == "__main__":
    main()
