"""The viewer page of a bundled frame: its size, the time to build it, and how soon it is
interactive once opened in headless Chromium (Debian's chromium + chromium-driver).

    python benchmarks/bench_viewer.py                       # scene.png, default stack
    python benchmarks/bench_viewer.py --screenshot docs/viewer.png

"Interactive" is ``window.lfInteractiveMs`` (handlers attached, first frame set) and "ready"
``window.lfReadyMs`` (every stack frame decoded), both from the page's time origin. The peer is a
page holding one stack frame as a single data: URI <img>, opened the same way in the same run.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import platform
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _driver(width: int, height: int):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", f"--window-size={width},{height}",
                "--no-first-run", "--disable-extensions", "--disable-background-networking"):
        opts.add_argument(arg)
    return webdriver.Chrome(options=opts, service=Service(executable_path="/usr/bin/chromedriver"))


def _open(driver, url: str, ready_js: str) -> float:
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get("about:blank")
    driver.get(url)
    WebDriverWait(driver, 30).until(lambda d: d.execute_script(f"return ({ready_js}) != null"))
    return float(driver.execute_script(f"return {ready_js}"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frame", default=str(ROOT / "data" / "synthetic" / "scene.png"))
    ap.add_argument("--planes", type=int, default=None)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--screenshot", default=None, help="Also save a screenshot of the page focused on the cup.")
    args = ap.parse_args()

    import cv2
    import numpy as np

    from lfring.cli._options import load_views
    from lfring.viewer import write_viewer

    tmp = Path(tempfile.mkdtemp(prefix="bench_viewer_"))
    page = tmp / "viewer.html"
    t = time.perf_counter()
    views, cal, name = load_views(args.frame, None)
    write_viewer(page, views, cal, num_planes=args.planes, title=Path(args.frame).name,
                 metadata={"input": Path(args.frame).name, "calibration": name})
    build_s = time.perf_counter() - t
    text = page.read_text()
    data = json.loads(re.search(r'<script id="lf-data" type="application/json">(.*?)</script>', text, re.S).group(1))
    peer = tmp / "peer.html"
    peer.write_text(f'<!DOCTYPE html><html><body><img id="i" src="{data["frames"][0]}"><script>'
                    'document.getElementById("i").decode().then(function () { window.peerMs = performance.now(); });'
                    '</script></body></html>')

    mib = page.stat().st_size / 2**20
    driver = _driver(900, 1000)
    try:
        inter, ready, peer_ms = [], [], []
        for _ in range(args.runs):
            ready.append(_open(driver, page.as_uri(), "window.lfReadyMs"))
            inter.append(float(driver.execute_script("return window.lfInteractiveMs")))
            peer_ms.append(_open(driver, peer.as_uri(), "window.peerMs"))
        if args.screenshot:
            _screenshot(driver, page, data, Path(args.screenshot))
    finally:
        driver.quit()
        shutil.rmtree(tmp, ignore_errors=True)

    med = statistics.median
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}, load {os.getloadavg()[0]:.2f}")
    print(f"{Path(args.frame).name}: {data['width']} x {data['height']} px reference frame, {len(data['frames'])} stack frames "
          f"{data['depths_m'][0]:.3f}-{data['depths_m'][-1]:.3f} m; page {mib:.2f} MiB; built in {build_s:.2f} s "
          f"(load, split, stack, depth, all-in-focus, encode); median of {args.runs} opens")
    print("| what | median ms | min ms | max ms | x peer time |")
    print("|---|---|---|---|---|")
    for label, xs in (("peer: one stack frame as a data: URI <img>, decoded", peer_ms),
                      ("viewer interactive (handlers attached, first frame set)", inter),
                      ("viewer ready (every stack frame decoded)", ready)):
        print(f"| {label} | {med(xs):.0f} | {min(xs):.0f} | {max(xs):.0f} | {med(xs) / med(peer_ms):.2f} |")


def _screenshot(driver, page: Path, data: dict, out: Path) -> None:
    """The page focused on the cup (a click near the reference frame's upper left object),
    the cursor on the book, saved as a PNG (quantised to keep it small)."""
    import cv2
    import numpy as np
    from selenium.webdriver.common.action_chains import ActionChains

    driver.set_window_size(760, 900)
    _open(driver, page.as_uri(), "window.lfReadyMs")
    el = driver.find_element("id", "lf-view")
    w, h = driver.execute_script("var r = arguments[0].getBoundingClientRect(); return [r.width, r.height]", el)

    def at(x, y):
        return int(round((x + 0.5) * w / data["width"] - w / 2)), int(round((y + 0.5) * h / data["height"] - h / 2))

    ActionChains(driver).move_to_element_with_offset(el, *at(231, 264)).click().perform()
    time.sleep(0.4)
    ActionChains(driver).move_to_element_with_offset(el, *at(508, 400)).perform()
    png = base64.b64decode(driver.get_screenshot_as_base64())
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"screenshot: {out} ({out.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
