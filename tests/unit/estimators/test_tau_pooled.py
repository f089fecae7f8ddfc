"""Pooled τc covariances from the engine's sums (edgedsm.estimators.tau_pooled) equal the sums of
the per-pixel covariances, for regions and blocks, sliding and tumbling, with and without numba
(what the measurement core fits them to: tests/unit/measurement/test_tau.py)."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow, tau_pooled
from edgedsm.estimators.snapshot import TauSnapshot, tau_covariances
from edgedsm.sim import Simulator, scene_from_dict

SIZE, LAG, MAX_LAG = 30, 3, 8


def _frames(count: int, bits: int = 8, tau: float = 5.0) -> np.ndarray:
    scene = {"scene": {"size": SIZE, "frames": count, "seed": 11},
             "activity": {"tau_c": tau, "regions": [{"shape": "rect", "x": 0, "y": 0, "width": SIZE // 2,
                                                      "height": SIZE, "tau_c": 2 * tau}]},
             "detector": {"n_max": 1000, "bits": bits}}
    frames = np.stack(list(Simulator(scene_from_dict(scene)).frames()))
    frames[:, 3, :7] = frames[0, 3, :7]  # constant pixels: σ = 0
    return frames


def _snapshot(mode: str, window: int = 60, bits: int = 8) -> tuple[TauSnapshot, np.ndarray]:
    frames = _frames(window + 23, bits)
    engine = SlidingWindow((SIZE, SIZE), window=window, lag=LAG, bits=bits, estimators=("s1", "tau_c"), mode=mode,
                           max_lag=MAX_LAG)
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))
    return engine.tau_snapshot(), frames


def _pooled(snapshot: TauSnapshot, pixels: np.ndarray) -> tuple[np.ndarray, float]:
    return tau_pooled.pooled_covariances(snapshot.window, snapshot.total, snapshot.total_sq, snapshot.products,
                                         snapshot.edges, snapshot.ends, pixels, snapshot.lags)


@pytest.fixture(params=["compiled", "numpy"])
def path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    if request.param == "numpy":
        monkeypatch.setattr(tau_pooled, "numba", None)
    elif tau_pooled.numba is None:
        pytest.skip("numba is not installed")
    return str(request.param)


@pytest.mark.parametrize(("mode", "bits"), [("sliding", 8), ("tumbling", 8), ("sliding", 12)])
def test_a_region_pool_is_the_sum_of_its_pixels_covariances(path: str, mode: str, bits: int) -> None:
    snapshot, _ = _snapshot(mode, bits=bits)
    mask = np.zeros((SIZE, SIZE), bool)
    mask[2:25, 4:29] = True
    pixels = np.flatnonzero(mask)
    cov, var = tau_covariances(snapshot, pixels)
    pooled_cov, pooled_var = _pooled(snapshot, pixels)
    np.testing.assert_allclose(pooled_cov, cov.sum(axis=1), rtol=1e-12, atol=1e-9)
    assert pooled_var == pytest.approx(float(var.sum()), rel=1e-12)
    assert pooled_var > 0 and np.all(np.isfinite(pooled_cov))


@pytest.mark.parametrize("block", [1, 4, 7])
def test_a_block_pool_is_the_sum_over_its_blocks_pixels(path: str, block: int) -> None:
    snapshot, _ = _snapshot("sliding")
    cov, var = tau_covariances(snapshot)
    pooled_cov, pooled_var = tau_pooled.block_covariances(snapshot.window, snapshot.shape, block, snapshot.total,
                                                          snapshot.total_sq, snapshot.products, snapshot.edges,
                                                          snapshot.ends, snapshot.lags)
    rows = cols = -(-SIZE // block)
    assert snapshot.lags.tolist() == [1, 2, 3, 4, 6, 8]  # multi-tau: the first and last k frames skip 5 and 7
    assert pooled_cov.shape == (snapshot.lags.size, rows, cols) and pooled_var.shape == (rows, cols)
    for r, c in [(0, 0), (rows - 1, cols - 1), (rows // 2, 1)]:  # inner and edge (partial) blocks
        inside = np.zeros((SIZE, SIZE), bool)
        inside[r * block:(r + 1) * block, c * block:(c + 1) * block] = True
        np.testing.assert_allclose(pooled_cov[:, r, c], cov[:, inside.ravel()].sum(axis=1), rtol=1e-12, atol=1e-9)
        assert pooled_var[r, c] == pytest.approx(float(var[inside.ravel()].sum()), rel=1e-12, abs=1e-12)
