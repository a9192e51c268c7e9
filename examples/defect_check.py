"""Defect check over a folder of parts: the script an inspection engineer starts from.

Every raw frame is split into the ring's four views, swept over a narrow band of depths around
the working plane, and checked: regions of confident pixels whose depth leaves the plane by
more than the tolerance are defects. A part passes only when at least --min-coverage (80 %) of
it (the pixels whose surface lies near the plane) was checked with confident depth; a frame that
is too dark, too flat, shows nothing at the plane or was not checked enough cannot be judged, and
never passes. One line per part, a JSON report and an annotated PNG per part in the output folder
(the unchecked area hatched), and an exit code for a shell loop or a CI job: 0 when every part
passed, 1 when any part has defects, else 2 when a file or value was bad, else 3 when a part
cannot be judged.

    python examples/defect_check.py data/synthetic/part_*.png --plane 0.3 --tolerance 0.008 -o out/

Adapt it: pass --calib with your camera's calibration, an ROI around the part (``roi=(x, y, w, h)``
in pixels of the central view), or ``reference_depth_m=`` a golden part's depth map.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import lfring
from lfring.calibration.defaults import default_calibration
from lfring.inspect import MIN_COVERAGE, inspect_frame, write_report
from lfring.optics import load_device


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", nargs="+", type=Path, help="raw frames (PNG/TIFF/DNG) of the parts")
    ap.add_argument("--plane", type=float, required=True, help="working plane, metres from the main lens")
    ap.add_argument("--tolerance", type=float, required=True, help="largest accepted deviation, metres")
    ap.add_argument("--calib", type=Path, help="calibration JSON (default: the built-in one for the frame size)")
    ap.add_argument("-o", "--output", type=Path, required=True, help="folder for the reports")
    ap.add_argument("--min-coverage", type=float, default=MIN_COVERAGE,
                    help=f"smallest fraction of the part checked with confident depth for a pass (default {MIN_COVERAGE})")
    ap.add_argument("--overwrite", action="store_true", help="replace reports from an earlier run")
    args = ap.parse_args(argv)

    failed = errors = unjudged = 0
    calibration = lfring.RingCalibration.load(args.calib) if args.calib else None
    for path in args.frames:
        try:
            # Raw counts -> linear RGB in [0, 1] (black and white levels from the file's sidecar).
            image = lfring.demosaic(lfring.load_raw(path))
            # One calibration per camera and binning; the built-in one matches the twin's frames.
            cal = calibration or default_calibration((image.shape[1], image.shape[0]))[0]
            views = lfring.split_views(image, cal)
            # The device (binned to the frame) converts defect areas to mm^2; optional.
            device = load_device("prototype")
            device = device.binned(device.sensor_width_px // image.shape[1])
            result = inspect_frame(views, cal, plane_m=args.plane, tolerance_m=args.tolerance, device=device,
                                   min_coverage=args.min_coverage)
            # JSON (verdict, settings, every defect's box, area, signed deviation) and a PNG.
            stem = args.output / path.stem
            write_report(result, f"{stem}_inspect.json", image_path=f"{stem}_inspect.png", overwrite=args.overwrite,
                         raw=str(path))
        except lfring.LfringError as exc:  # a bad file or value: report it, go on with the others
            print(f"ERROR {path}: {exc}")
            errors += 1
            continue
        if result.verdict == "pass":
            print(f"PASS  {path} (checked {result.coverage:.0%} of the part)")
        elif result.verdict == "cannot_judge":  # not checked is not passed: say why
            unjudged += 1
            print(f"CANNOT JUDGE  {path}: {result.reason}")
        else:
            failed += 1
            # Deviations are positive towards the camera (bumps) and negative away (dents).
            worst = ", ".join(f"{d.kind} {d.deviation_m * 1e3:+.1f} mm at {d.bbox_px[:2]}" for d in result.defects)
            n = len(result.defects)
            print(f"FAIL  {path}: {n} defect{'s' if n != 1 else ''} ({worst})")
    n = len(args.frames)
    if failed or errors or unjudged:
        print(f"{failed} of {n} parts failed, {unjudged} cannot be judged, {errors} could not be read")
    else:
        print(f"all {n} parts passed")
    return 1 if failed else 2 if errors else 3 if unjudged else 0


if __name__ == "__main__":
    sys.exit(main())
