"""The torch twin of the SGM aggregation against the numba kernel."""

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")
pytest.importorskip("kornia", reason="the torch extra is not installed")

from lfring.depth.sgm import sgm_aggregate, sgm_aggregate_torch  # noqa: E402
from lfring.errors import InvalidInputError  # noqa: E402


def _volume(seed=0, shape=(7, 11, 13)):
    rng = np.random.default_rng(seed)
    cost = rng.random(shape).astype(np.float32)
    cost[3, 2, 5] = np.nan
    cost[:, 6, 0] = np.inf
    guide = rng.random(shape[1:]).astype(np.float32)
    return cost, guide


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("edge_scale", [None, 0.05])
def test_parity_with_numba(paths, edge_scale, device):
    cost, guide = _volume()
    want = sgm_aggregate(cost, guide=guide, p1=0.05, p2=0.3, paths=paths, edge_scale=edge_scale)
    got = sgm_aggregate_torch(cost, guide=guide, p1=0.05, p2=0.3, paths=paths, edge_scale=edge_scale, device=device)
    assert isinstance(got, np.ndarray) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_parity_default_penalties_and_tensor_io():
    cost, guide = _volume(seed=1, shape=(9, 8, 10))
    want = sgm_aggregate(cost, guide=guide, paths=8)
    got = sgm_aggregate_torch(torch.from_numpy(cost), guide=torch.from_numpy(guide), paths=8)
    assert isinstance(got, torch.Tensor)
    np.testing.assert_allclose(got.cpu().numpy(), want, rtol=1e-5, atol=1e-5)


def test_errors():
    cost, _ = _volume()
    with pytest.raises(InvalidInputError, match="paths must be one of"):
        sgm_aggregate_torch(cost, paths=2, p1=0.1, p2=1.0)
    with pytest.raises(InvalidInputError, match=r"\(N, h, w\)"):
        sgm_aggregate_torch(cost[0], p1=0.1, p2=1.0)
    with pytest.raises(InvalidInputError, match="guide must be"):
        sgm_aggregate_torch(cost, guide=np.zeros((3, 3)), p1=0.1, p2=1.0)
    with pytest.raises(InvalidInputError, match="p1 must be >= 0"):
        sgm_aggregate_torch(cost, p1=-1.0, p2=1.0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(guide="nan"), "finite numeric"),  # one NaN guide pixel would spread NaN along the paths
    (dict(guide="bool"), "finite numeric"),
    (dict(guide="four channels"), "image of the cost"),
    (dict(p1="1"), "p1 must be a number"),
    (dict(p1=np.array([1.0, 2.0])), "p1 must be a number"),
    (dict(edge_scale="a", guide="ok"), "edge_scale must be a number"),
    (dict(edge_scale=0.0, guide="ok"), "edge_scale must be > 0"),
    (dict(paths=4.0), "paths must be one of"),
    (dict(paths=[4]), "paths must be one of"),
])
def test_bad_inputs_are_refused_as_the_numba_version_refuses_them(kwargs, message):
    cost, guide = _volume()
    guides = {"nan": np.where(np.arange(guide.size).reshape(guide.shape) == 7, np.nan, guide),
              "bool": guide > 0.5, "four channels": np.repeat(guide[..., None], 4, axis=2), "ok": guide}
    kwargs = {k: guides[v] if k == "guide" else v for k, v in kwargs.items()}
    kwargs = {"p1": 0.1, "p2": 1.0, **kwargs}
    for fn in (sgm_aggregate_torch, sgm_aggregate):
        with pytest.raises(InvalidInputError, match=message):
            fn(cost, **kwargs)
