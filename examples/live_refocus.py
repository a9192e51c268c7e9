"""Live-style loop: refocus every incoming frame at one fixed depth with the fast path.

An inspection camera delivers frames one after another and the line wants each one refocused on
the working plane. The geometry (homographies, masks, normalisation) depends only on the
calibration, the depth and the frame size, so it is built once (`lfring.Refocuser`) and every
frame then costs a demosaic, a split and four warps.

Run it on the bundled samples (frames are read from disk here; swap `frames()` for your camera's
grab loop):

    python examples/live_refocus.py data/synthetic/part_*.png --depth 0.3 --repeat 5 -o live_out/

It prints a line per frame with the time of each step and ends with the frame rate. A frame
that cannot be used (unreadable, truncated, of another size, or not a ring frame for the
calibration: an ordinary photograph) gets one ERROR line and the loop goes on; the exit code is
then 2. --no-check skips the ring-frame check (a check costs about a refocus).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import lfring
from lfring.calibration.defaults import default_calibration
from lfring.io.writers import encode_image, write_image


def frames(paths: list[str], repeat: int):
    """Stand-in for a camera: yields (name, path) pairs, `repeat` rounds over the files (the
    loop reads each; a camera would hand over the frame itself)."""
    for r in range(repeat):
        for p in paths:
            yield f"{Path(p).stem}#{r}", p


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Refocus a stream of frames at one depth.")
    ap.add_argument("frames", nargs="+", help="raw frames (PNG/TIFF with sidecars, or camera RAW)")
    ap.add_argument("--depth", type=float, required=True, help="working distance from the main lens [m]")
    ap.add_argument("--calib", default=None, help="calibration JSON (default: the built-in one for the frame size)")
    ap.add_argument("--repeat", type=int, default=1, help="rounds over the files, to see a steady frame rate")
    ap.add_argument("-o", "--output", default=None, help="folder for the refocused PNGs (default: not written)")
    ap.add_argument("--no-check", action="store_true", help="skip the check that each frame is a ring frame")
    args = ap.parse_args(argv)
    if not (args.depth > 0) or args.repeat < 1:
        ap.error("--depth must be positive metres and --repeat at least 1")
    out = Path(args.output) if args.output else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)

    refocuser = cal = None
    n, bad, t_all = 0, 0, time.perf_counter()
    for name, path in frames(args.frames, args.repeat):
        t0 = time.perf_counter()
        try:
            image = lfring.demosaic(lfring.load_raw(path))  # float32 RGB in [0, 1]
            if cal is None:  # the first good frame decides the calibration (and so the frame size)
                cal = lfring.RingCalibration.load(args.calib) if args.calib else default_calibration(image.shape[1::-1])[0]
            cal.check_frame(image.shape, what=name)  # every frame must match it
            if not args.no_check:
                checked = lfring.check_frame(image, cal)  # an ordinary photograph has no discs of light
                if not checked.ok:
                    raise lfring.InvalidInputError(f"not a ring frame for the calibration: {checked.message}")
            views = lfring.split_views(image, cal)  # (4, h, w, 3)
        except (lfring.LfringError, OSError) as exc:  # a bad frame: say so and take the next one
            print(f"ERROR {name}: {exc}")
            bad += 1
            continue
        t1 = time.perf_counter()
        if refocuser is None:  # built once: the per-frame work is four warps and a sum
            refocuser = lfring.Refocuser(cal, args.depth, interpolation="linear")
        img = refocuser(views)
        t2 = time.perf_counter()
        if out is not None:
            write_image(out / f"{name.replace('#', '_')}_refocus.png", encode_image(img, 8, "srgb"))
        note = " (builds the Refocuser)" if n == 0 else ""
        n += 1
        print(f"{name}: demosaic+split {1e3 * (t1 - t0):.1f} ms, refocus {1e3 * (t2 - t1):.1f} ms{note}, "
              f"mean level {img.mean():.3f}")
    elapsed = time.perf_counter() - t_all
    print(f"{n} frames at {args.depth:g} m in {elapsed:.2f} s: {n / elapsed:.1f} frames/s (reading from disk included)"
          + (f"; {bad} frames could not be used" if bad else ""))
    return 2 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
