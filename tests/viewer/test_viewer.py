"""The interactive viewer: the page's data against the twin's ground truth, and the page itself
driven in a real browser (Debian's chromium + chromium-driver through selenium).

Outside CI the browser tests skip, saying why, when no Chromium is installed; with CI=true they
never skip.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from lfring.errors import InvalidInputError

DATA = Path(__file__).resolve().parents[2] / "data" / "synthetic"
OBJECTS = {"cup": 0.3, "book": 0.5, "chessboard": 1.0}
PLANES = 12  # a reduced stack keeps the browser tests quick
MAX_BYTES = 15 * 1024 * 1024
CHROMIUM = ("/usr/bin/chromium", "/usr/bin/chromium-browser")
CHROMEDRIVER = "/usr/bin/chromedriver"
SCREENSHOT_DIR_ENV = "LFRING_VIEWER_SCREENSHOT_DIR"


@pytest.fixture(scope="module")
def scene():
    from lfring.cli._options import load_views

    views, cal, name = load_views(str(DATA / "scene.png"), None)
    return views, cal, name


@pytest.fixture(scope="module")
def page(scene, tmp_path_factory):
    """The viewer of scene.png, built once for the module."""
    from lfring.viewer import write_viewer

    views, cal, name = scene
    path = tmp_path_factory.mktemp("viewer") / "scene_viewer.html"
    write_viewer(path, views, cal, num_planes=PLANES, title="scene.png", metadata={"input": "scene.png", "calibration": name})
    return path


def _data(path) -> dict:
    text = Path(path).read_text()
    return json.loads(re.search(r'<script id="lf-data" type="application/json">(.*?)</script>', text, re.S).group(1))


def object_points(shape_hw) -> dict:
    """A point deep inside each object, in reference ('center') pixels, from the ground truth:
    every view's depth map moved into the centre frame by the exact homography at the object's
    depth, the pixels where all four views see the object, and of those the one farthest from
    the object's edge (and from the frame's border)."""
    truth = json.loads((DATA / "scene_truth" / "truth.json").read_text())
    h, w = shape_hw
    out = {}
    for name, z in OBJECTS.items():
        surface = next(s for s in truth["scene"]["surfaces"] if s["name"] == name)
        assert surface["depth_m"] == z and surface["tilt_deg"] == [0.0, 0.0]
        seen = np.ones((h, w), np.uint8)
        for k, hmat in enumerate(truth["H_center_from_view_at_surface_depths"][f"{z:g}"]):
            depth = tifffile.imread(DATA / "scene_truth" / f"depth_view{k}.tiff")
            mask = (np.abs(depth - z) < 1e-6).astype(np.uint8)
            seen &= cv2.warpPerspective(mask, np.array(hmat, dtype=np.float64), (w, h), flags=cv2.INTER_NEAREST)
        seen[[0, -1], :] = 0
        seen[:, [0, -1]] = 0
        dist = cv2.distanceTransform(seen, cv2.DIST_L2, 5)
        y, x = np.unravel_index(int(dist.argmax()), dist.shape)
        assert dist[y, x] > 15, name  # a point well inside the object
        out[name] = (int(x), int(y))
    return out


def _step_around(depths_m, z) -> float:
    """The larger gap between the stack frames on either side of z."""
    d = np.asarray(depths_m)
    k = int(np.argmin(np.abs(d - z)))
    gaps = [abs(d[k] - d[j]) for j in (k - 1, k + 1) if 0 <= j < len(d)]
    return max(gaps)


# -- the page's content ---------------------------------------------------------------------------
def test_page_is_self_contained_and_its_depths_match_the_truth(page, scene):
    text = page.read_text()
    assert page.stat().st_size <= MAX_BYTES
    assert "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'" in text
    # Nothing but data: URIs: no http(s), protocol-relative or file references anywhere.
    assert not re.search(r'(src|href)\s*=\s*"(?!data:)[^"]+"', text)
    assert "http://" not in text.replace("http://www.w3.org/2000/svg", "") and "https://" not in text
    d = _data(page)
    views, cal, _ = scene
    assert d["width"] == views.shape[2] and d["height"] == views.shape[1]
    assert len(d["frames"]) == PLANES and all(f.startswith("data:image/jpeg;base64,") for f in d["frames"])
    assert d["depths_m"][0] == pytest.approx(cal.valid_depth_range_m[0])
    assert d["depths_m"][-1] == pytest.approx(cal.valid_depth_range_m[1])
    depth_mm = np.frombuffer(base64.b64decode(d["depth_mm_u16le"]), "<u2").reshape(d["height"], d["width"])
    conf = np.frombuffer(base64.b64decode(d["confidence_u8"]), np.uint8).reshape(depth_mm.shape)
    for name, (x, y) in object_points(depth_mm.shape).items():
        # The confident depths nearest the point (a chessboard square's inside has none).
        for r in (4, 8, 16, 32):
            win = depth_mm[y - r:y + r + 1, x - r:x + r + 1]
            ok = (win > 0) & (conf[y - r:y + r + 1, x - r:x + r + 1] >= round(0.5 * 255))
            if ok.sum() >= 8:
                break
        assert ok.sum() >= 8, name
        med_m = float(np.median(win[ok])) / 1e3
        assert abs(med_m - OBJECTS[name]) <= _step_around(d["depths_m"], OBJECTS[name]), (name, med_m)
    for key in ("all_in_focus", "depth_colour"):
        raw = base64.b64decode(d[key].split(",", 1)[1])
        img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape[:2] == depth_mm.shape, key


def test_overlays_and_bad_options(scene):
    from lfring.viewer import viewer_html

    views, cal, _ = scene
    mask = np.zeros(views.shape[1:3], bool)
    mask[:10] = True
    text = viewer_html(views, cal, num_planes=3, boxes=[(5, 6, 20, 10, "bump 1.2 mm"), {"x": 1, "y": 2, "w": 3, "h": 4}],
                       unchecked_mask=mask, image_format="webp")
    d = json.loads(re.search(r'type="application/json">(.*?)</script>', text, re.S).group(1))
    assert d["boxes"][0] == {"x": 5.0, "y": 6.0, "w": 20.0, "h": 10.0, "label": "bump 1.2 mm", "colour": "#ff2d2d"}
    assert d["boxes"][1]["label"] == ""
    png = base64.b64decode(d["unchecked"].split(",", 1)[1])
    rgba = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(rgba[..., 3] > 0, mask)
    assert d["frames"][0].startswith("data:image/webp;base64,")
    bad = [dict(num_planes=1), dict(num_planes=2), dict(boxes=[(0, 0, -1, 2)]), dict(boxes=[(0, 0, 1, 2, "x", "red")]),
           dict(unchecked_mask=mask[:5]),
           dict(image_format="gif"),
           dict(quality=0), dict(min_confidence=2.0), dict(focus_m=5.0), dict(num_planes=3, depth=object())]
    for kw in bad:
        with pytest.raises(InvalidInputError):
            viewer_html(views, cal, **kw)
    # Views that are not this calibration's are named as such, before any depth map is blamed.
    for wrong in (views[0], views[:, :600]):
        with pytest.raises(InvalidInputError, match="the calibration is for 4 views of 705 x 705 px"):
            viewer_html(wrong, cal, depth=object())


def test_a_stack_too_near_to_render_is_refused_before_any_depth_work(scene, monkeypatch):
    """The stack starts at the range's near end: nearer than where the views overlap it would be
    black or ghosted, as lfring refocus says, and the refusal comes before the depth estimate."""
    import lfring
    from lfring.calibration.overlap import nearest_renderable_depth_m
    from lfring.viewer import viewer_html

    views, cal, _ = scene
    near = nearest_renderable_depth_m(cal)
    monkeypatch.setattr(lfring, "estimate_depth", lambda *a, **k: pytest.fail("the depth was estimated"))
    for zmin in (0.5 * near, 0.95 * near):
        with pytest.raises(InvalidInputError, match=rf"zmin_m {zmin:g} m cannot be rendered: .* the nearest depth that "
                                                    rf"works with this calibration is {math.ceil(near * 1e4) / 1e4:g} m"):
            viewer_html(views, cal, zmin_m=zmin, zmax_m=1.0)


# -- the page in a browser ------------------------------------------------------------------------
def _chromium() -> str | None:
    for path in CHROMIUM:
        if Path(path).is_file():
            return path
    return shutil.which("chromium")


@pytest.fixture(scope="module")
def browser():
    in_ci = os.environ.get("CI", "").lower() == "true"
    binary = _chromium()
    missing = []
    if binary is None:
        missing.append("no Chromium at /usr/bin/chromium (apt-get install chromium chromium-driver)")
    if not Path(CHROMEDRIVER).is_file():
        missing.append(f"no chromedriver at {CHROMEDRIVER} (apt-get install chromium-driver)")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        missing.append("selenium is not installed (pip install '.[test]')")
    if missing:
        if in_ci:
            pytest.fail("browser test cannot run in CI: " + "; ".join(missing))
        pytest.skip("browser test skipped: " + "; ".join(missing))
    opts = webdriver.ChromeOptions()
    opts.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", "--window-size=900,1000",
                "--no-first-run", "--disable-extensions", "--disable-background-networking"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    # The driver's path is given, so selenium never runs its manager (nothing is downloaded).
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=CHROMEDRIVER))
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def opened(browser, page):
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(page.as_uri())
    WebDriverWait(browser, 30).until(lambda d: d.execute_script("return document.documentElement.dataset.lfReady === '1'"))
    return browser


def _pointer_at(driver, x, y, *, click: bool):
    """Move the mouse to reference pixel (x, y) of the image (and click there)."""
    from selenium.webdriver.common.action_chains import ActionChains

    el = driver.find_element("id", "lf-view")
    w_px, h_px = driver.execute_script("return [arguments[0].naturalWidth, arguments[0].naturalHeight]", el)
    rect = driver.execute_script("var r = arguments[0].getBoundingClientRect(); return [r.width, r.height]", el)
    # selenium 4 measures offsets from the element's centre, in CSS pixels.
    dx = (x + 0.5) * rect[0] / w_px - rect[0] / 2
    dy = (y + 0.5) * rect[1] / h_px - rect[1] / 2
    chain = ActionChains(driver).move_to_element_with_offset(el, int(round(dx)), int(round(dy)))
    (chain.click() if click else chain).perform()


def test_clicking_an_object_focuses_at_its_depth(opened, page):
    d = _data(page)
    points = object_points((d["height"], d["width"]))
    for name in ("book", "cup", "chessboard"):  # the start (mid-range) is none of them
        _pointer_at(opened, *points[name], click=True)
        shown = float(opened.find_element("id", "lf-focus-depth").text)
        z = OBJECTS[name]
        assert abs(shown - z) <= _step_around(d["depths_m"], z) + 1e-9, (name, shown)
        assert shown in [round(v, 3) for v in d["depths_m"]]
        src = opened.find_element("id", "lf-view").get_attribute("src")
        assert src == d["frames"][[round(v, 3) for v in d["depths_m"]].index(shown)]


def test_cursor_reads_depth_in_mm_and_keys_step_the_focus(opened, page):
    from selenium.webdriver.common.keys import Keys

    d = _data(page)
    x, y = object_points((d["height"], d["width"]))["book"]
    # The pixel's own estimate: read back exactly as the page's data holds it.
    depth_mm = np.frombuffer(base64.b64decode(d["depth_mm_u16le"]), "<u2").reshape(d["height"], d["width"])
    _pointer_at(opened, x, y, click=False)
    text = opened.find_element("id", "lf-cursor-depth").text
    m = re.fullmatch(r"(\d+) mm", text)
    assert m, text
    px, py = (int(v) for v in opened.find_element("id", "lf-cursor-xy").text.split(","))
    assert abs(px - x) <= 1 and abs(py - y) <= 1
    assert int(m.group(1)) == int(depth_mm[py, px])
    assert abs(int(m.group(1)) / 1e3 - 0.5) <= _step_around(d["depths_m"], 0.5)
    assert 0 <= float(opened.find_element("id", "lf-cursor-confidence").text) <= 1
    # Arrow keys step through the stack's frames.
    _pointer_at(opened, *object_points((d["height"], d["width"]))["cup"], click=True)
    z = [round(v, 3) for v in d["depths_m"]]
    k = z.index(float(opened.find_element("id", "lf-focus-depth").text))
    opened.find_element("tag name", "body").send_keys(Keys.ARROW_RIGHT)
    assert float(opened.find_element("id", "lf-focus-depth").text) == z[min(k + 1, len(z) - 1)]
    opened.find_element("tag name", "body").send_keys(Keys.ARROW_LEFT, Keys.ARROW_LEFT)
    assert float(opened.find_element("id", "lf-focus-depth").text) == z[max(k - 1, 0)]


def test_toggles_and_no_network_requests(opened, page, tmp_path_factory):
    d = _data(page)
    view = opened.find_element("id", "lf-view")
    opened.find_element("id", "lf-toggle-aif").click()
    assert view.get_attribute("src") == d["all_in_focus"]
    opened.find_element("id", "lf-toggle-aif").click()
    opened.find_element("id", "lf-toggle-depth").click()
    assert opened.find_element("id", "lf-depth-layer").is_displayed()
    assert opened.find_element("id", "lf-colour-bar").is_displayed()
    opened.find_element("id", "lf-toggle-lowconf").click()
    assert opened.find_element("id", "lf-lowconf-layer").is_displayed()
    x, y = object_points((d["height"], d["width"]))["book"]
    _pointer_at(opened, x, y, click=True)
    shot_dir = Path(os.environ.get(SCREENSHOT_DIR_ENV) or tmp_path_factory.mktemp("shots"))
    shot = shot_dir / "viewer_scene.png"
    assert opened.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
    # Every request the page made: only the page itself and data: URIs.
    page_url = page.as_uri()
    urls = []
    for entry in opened.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        if msg["method"] == "Network.requestWillBeSent":
            urls.append(msg["params"]["request"]["url"])
    assert page_url in urls
    assert [u for u in urls if u != page_url and not u.startswith("data:")] == []
    resources = opened.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert [u for u in resources if not u.startswith("data:")] == []


def test_phone_sized_screen(opened, page):
    """On a 390 x 844 px screen the image and the controls fit the width, and a tap refocuses."""
    d = _data(page)
    opened.set_window_size(390, 844)
    try:
        opened.execute_script("window.dispatchEvent(new Event('resize'))")
        inner_w, scroll_w = opened.execute_script("return [window.innerWidth, document.documentElement.scrollWidth]")
        assert inner_w <= 400 and scroll_w <= inner_w
        for el_id in ("lf-view", "lf-slider", "lf-toggle-depth", "lf-focus-depth"):
            el = opened.find_element("id", el_id)
            assert el.is_displayed(), el_id
            right = opened.execute_script("return arguments[0].getBoundingClientRect().right", el)
            assert right <= inner_w, el_id
        _pointer_at(opened, *object_points((d["height"], d["width"]))["chessboard"], click=True)
        assert abs(float(opened.find_element("id", "lf-focus-depth").text) - 1.0) <= _step_around(d["depths_m"], 1.0)
    finally:
        opened.set_window_size(900, 1000)


# -- batch and inspect write viewers -------------------------------------------------------------
def test_batch_viewer_reuses_the_frames_depth_map(tmp_path):
    from lfring.cli.main import main

    out = tmp_path / "b"
    assert main(["batch", str(DATA / "scene.png"), "-o", str(out), "--depth", "--zmin", "0.3", "--zmax", "1.0",
                 "--viewer", "--workers", "1", "--no-progress"]) == 0
    page = out / "scene_viewer.html"
    d = _data(page)
    assert page.stat().st_size <= MAX_BYTES and d["metadata"]["input"].endswith("scene.png")
    depth = tifffile.imread(out / "scene_depth.tiff")
    depth_mm = np.frombuffer(base64.b64decode(d["depth_mm_u16le"]), "<u2").reshape(depth.shape)
    known = np.isfinite(depth)
    assert np.array_equal(depth_mm > 0, known)
    assert np.array_equal(depth_mm[known], np.rint(depth[known].astype(np.float64) * 1e3))
    record = json.loads((out / "scene.lfring.json").read_text())
    assert "scene_viewer.html" in json.dumps(record)


def test_inspect_viewer_shows_the_defects_and_the_unchecked_area(tmp_path, browser):
    from lfring.cli.main import main

    out = tmp_path / "i"
    code = main(["inspect", str(DATA / "part_defects.png"), "--plane", "0.3", "--tolerance", "0.008", "-o", str(out),
                 "--viewer"])
    assert code == 1  # the part has a bump and a dent
    report = json.loads((out / "part_defects_inspect.json").read_text())
    page = out / "part_defects_viewer.html"
    d = _data(page)
    assert len(d["boxes"]) == report["num_defects"] == 2
    for box, defect in zip(d["boxes"], report["defects"]):
        b = defect["bbox_px"]
        assert (box["x"], box["y"], box["w"], box["h"]) == (b["x"], b["y"], b["w"], b["h"])
        assert box["label"].startswith(f"{defect['id']} {defect['kind']}")
        # Coloured as the annotated image draws them: bumps red, dents blue.
        assert box["colour"] == {"bump": "#ff2828", "dent": "#288cff"}[defect["kind"]]
    assert {b["colour"] for b in d["boxes"]} == {"#ff2828", "#288cff"}
    # The unchecked area is the part the inspection could not judge (1 - its coverage of the part)
    # and where the part may run on beyond two views' sight (its share of the part).
    png = base64.b64decode(d["unchecked"].split(",", 1)[1])
    alpha = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)[..., 3]
    part_px = report["stats"]["part_fraction"] * alpha.size
    beyond = report["stats"]["beyond_sight_fraction"]
    assert beyond > 0.1  # the plate reaches the frame's corners
    assert (alpha > 0).sum() == pytest.approx((1 - report["coverage"] + beyond) * part_px,
                                              abs=2e-4 * part_px + 2)  # the report's fractions have 4 decimals
    # The stack spans the inspection's depth band.
    assert d["depths_m"][0] == pytest.approx(report["settings"]["zmin_m"])
    assert d["depths_m"][-1] == pytest.approx(report["settings"]["zmax_m"])
    # In the browser: the boxes are drawn over the image, and a click on a box refocuses near the plane.
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(page.as_uri())
    WebDriverWait(browser, 30).until(lambda drv: drv.execute_script("return document.documentElement.dataset.lfReady === '1'"))
    assert browser.find_element("id", "lf-boxes-layer").is_displayed()
    assert browser.find_element("id", "lf-unchecked-layer").is_displayed()
    assert len(browser.find_elements("css selector", "#lf-boxes-layer rect")) == 2
    # It opens focused at the working plane (the frame nearest it in disparity).
    inv = [1 / (z - d["depth_origin_m"]) for z in d["depths_m"]]
    k = int(np.argmin(np.abs(np.array(inv) - 1 / (0.3 - d["depth_origin_m"]))))
    assert browser.find_element("id", "lf-focus-depth").text == f"{d['depths_m'][k]:.3f}"
    shot_dir = Path(os.environ.get(SCREENSHOT_DIR_ENV) or tmp_path)
    assert browser.save_screenshot(str(shot_dir / "viewer_inspect.png"))


def test_the_stack_is_refocused_as_lfring_refocus_and_says_how(scene):
    """The focal stack is depth-aware by default (as lfring refocus), from the page's own depth
    map, and the metadata panel says which method and aperture made it; shift-and-add on demand."""
    from lfring import estimate_depth
    from lfring.focus import focal_stack
    from lfring.viewer import viewer_html

    views, cal, _ = scene
    depth = estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, num_planes=5)
    pages = {m: json.loads(re.search(r'type="application/json">(.*?)</script>',
                                     viewer_html(views, cal, depth=depth, method=m, aperture=0.7 if m == "depth-aware" else None),
                                     re.S).group(1))
             for m in ("depth-aware", "shift-and-add")}
    assert pages["depth-aware"]["metadata"]["refocus_method"] == "depth-aware"
    assert pages["depth-aware"]["metadata"]["aperture"] == 0.7
    assert pages["shift-and-add"]["metadata"]["refocus_method"] == "shift-and-add"
    assert pages["shift-and-add"]["metadata"]["aperture"] is None
    zs = pages["depth-aware"]["depths_m"]

    def frame(d, i):
        raw = base64.b64decode(d["frames"][i].split(",", 1)[1])
        return cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32)

    from lfring.io.writers import encode_image

    for m, kw in (("depth-aware", {"aperture": 0.7, "depth": depth}), ("shift-and-add", {})):
        want = encode_image(focal_stack(views, cal, zs[:1], method=m, **kw)[0], 8, "srgb").astype(np.float32)
        assert np.abs(frame(pages[m], 0) - want).mean() < 2.0, m  # JPEG's loss only
    assert np.abs(frame(pages["depth-aware"], 0) - frame(pages["shift-and-add"], 0)).mean() > 2.0
    with pytest.raises(InvalidInputError, match="for method='depth-aware'"):
        viewer_html(views, cal, depth=depth, method="shift-and-add", aperture=0.5)


def test_the_depth_range_is_depth_aware_refocusings():
    """The page's depth map (which its depth-aware stack renders from) takes the range of
    lfring.focus.depth_aware.estimation_range: a grid pair's open range is refused as by
    lfring.refocus, and given its near end the far end follows as for refocusing."""
    from lfring.calibration import RingCalibration
    from lfring.focus import refocus
    from lfring.focus.depth_aware import estimation_range
    from lfring.viewer import viewer_html

    rng = np.random.default_rng(2)
    tex = cv2.GaussianBlur(rng.random((64, 120, 3), dtype=np.float32), (0, 0), 1.0)
    views = np.stack([tex[:, 12:108], tex[:, 8:104]])  # 4 px of disparity: 30 m at 120 px m
    cal = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    for call in (lambda: viewer_html(views, cal), lambda: refocus(views, cal, 30.0, method="depth-aware")):
        with pytest.raises(InvalidInputError, match="no upper depth bound, and none follows from it"):
            call()
    d = json.loads(re.search(r'type="application/json">(.*?)</script>', viewer_html(views, cal, zmin_m=8.0), re.S).group(1))
    assert (d["zmin_m"], d["zmax_m"]) == estimation_range(cal, zmin_m=8.0)
