import matplotlib
import pytest

matplotlib.use("Agg")


def _torch_devices() -> list[str]:
    """The torch devices of this machine: the CPU always, CUDA when present (so a machine with a
    GPU runs every torch test on it too)."""
    try:
        import torch
    except ImportError:
        return ["cpu"]
    return ["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]


@pytest.fixture(params=_torch_devices())
def device(request):
    """Each torch device present, by name (as kornia's test suite does)."""
    return request.param


@pytest.fixture
def renderers_made(monkeypatch):
    """A list that grows by one each time a depth-of-field renderer (``DepthOfField``) is
    prepared, while the test runs: clear it to count from a point on."""
    import lfring.focus.depth_aware as depth_aware

    made = []
    init = depth_aware.DepthOfField.__init__

    def counted(self, *args, **kwargs):
        made.append(True)
        init(self, *args, **kwargs)

    monkeypatch.setattr(depth_aware.DepthOfField, "__init__", counted)
    return made


@pytest.fixture(scope="session")
def prototype():
    from lfring.optics import load_device

    return load_device("prototype")


@pytest.fixture(scope="session")
def twin(prototype):
    """The twin's three-depth scene (binned, realistic noise), its calibration, the views, view
    0's true depth, its evaluation mask and the default depth estimate in view 0's frame."""
    from lfring.calibration import RingCalibration
    from lfring.depth import estimate_depth
    from lfring.depth.metrics import evaluation_mask
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.synth import render
    from lfring.synth.presets import three_depth_scene
    from lfring.views import split_views

    r = render(prototype, three_depth_scene(), binning=2, noise="realistic", seed=3)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    gt = r.depth_m[0]
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, num_planes=41, reference=0)
    return r, cal, views, gt, evaluation_mask(gt, r.views_sharp[0]), res


@pytest.fixture(scope="session")
def hard_twin(prototype):
    """The twin's hard scene (slants, wires, a blank card, vignetting from 30 % to 96 % per view),
    4 x 4 binned with realistic noise, and its calibration."""
    from lfring.calibration import RingCalibration
    from lfring.synth import render
    from lfring.synth.presets import HARD_VIEW_FALLOFF, hard_scene

    r = render(prototype, hard_scene(), binning=4, pattern=None, view_falloff=HARD_VIEW_FALLOFF, noise="realistic", seed=3)
    return r, RingCalibration.from_optics(r.device, layout=r.layout)


@pytest.fixture(scope="session")
def parts(prototype):
    """The inspection tests' parts, rendered and inspected once: name -> (render, calibration,
    views, truth defects, inspection)."""
    from inspect_parts import PLANE, TOL, truth_defects, truth_deviation

    from lfring.calibration.defaults import default_calibration
    from lfring.inspect import inspect_frame
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.synth import render
    from lfring.synth.presets import part_scene
    from lfring.views import split_views

    cal = default_calibration((2456, 1842))[0]
    specs = {
        "good": dict(defect_heights_m=(), seed=21),
        "two": dict(defect_heights_m=(0.015, -0.013), defect_size_m=0.012, seed=22),
        # 12.5 mm is 0.52 px of disparity between neighbouring views at 0.3 m.
        "three": dict(defect_heights_m=(0.0125, -0.016, -0.0125), defect_size_m=0.0125, seed=23),
    }
    out = {}
    for name, kw in specs.items():
        r = render(prototype, part_scene(depth_m=PLANE, **kw), binning=2, noise="realistic", seed=kw["seed"])
        frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
        views = split_views(demosaic(frame), cal.layout)
        res = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
        out[name] = (r, cal, views, truth_defects(truth_deviation(r, cal, PLANE), TOL), res)
    return out
