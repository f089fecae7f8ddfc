"""τc in the streaming engine: equal to the batch reference on the same window (sliding and
tumbling, both kernels), exact integer sums, arguments."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, tau_c_bounds
from edgedsm.estimators.correlation_time import covariances
from edgedsm.sim import Simulator, scene_from_dict

KERNELS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])


def _scene_frames(count: int, bits: int = 8, size: int = 24) -> np.ndarray:
    scene = {"scene": {"size": size, "frames": count, "seed": 4},
             "activity": {"tau_c": 4.0, "regions": [{"shape": "rect", "x": 0, "y": 0, "width": size // 2,
                                                      "height": size, "tau_c": 12.0}]},
             "detector": {"n_max": 1000, "bits": bits},
             "phase_noise": {"alpha": 0.5, "tau_noise": 1.0, "model": "white"}, "ambient_light": {"eta": 0.2}}
    return np.stack(list(Simulator(scene_from_dict(scene)).frames()))


def _feed(engine: SlidingWindow, frames: np.ndarray) -> None:
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))


def _assert_equal_to_batch(engine: SlidingWindow, window: np.ndarray) -> None:
    expected = tau_c_bounds(window, engine.max_lag)
    got = engine.tau_c_bounds()
    np.testing.assert_allclose(got.tau, expected.tau, rtol=1e-9, atol=0)
    np.testing.assert_array_equal(got.status, expected.status)
    np.testing.assert_allclose(engine.maps()["tau_c"], expected.tau, rtol=1e-9, atol=0)
    mask = np.zeros(window.shape[1:], bool)
    mask[:, : window.shape[2] // 2] = True
    region = engine.region_tau_c(mask)
    reference = tau_c_bounds(window, engine.max_lag, mask=mask)
    assert region.status == reference.status
    assert region.tau == pytest.approx(reference.tau, rel=1e-9, abs=0)
    assert region.tau == reference.tau  # the same integers and float64 steps: bit for bit


@pytest.mark.parametrize("kernel", KERNELS)
def test_sliding_tau_c_equals_batch_at_every_step(kernel):
    frames = _scene_frames(90)
    engine = SlidingWindow((24, 24), 60, 5, estimators=["s1", "tau_c"], kernel=kernel, max_lag=12)
    for i, frame in enumerate(frames):
        engine.push(np.ascontiguousarray(frame))
        if i + 1 >= 60 and (i + 1) % 10 == 0:
            _assert_equal_to_batch(engine, frames[i + 1 - 60:i + 1])
    assert engine.max_lag == 12


@pytest.mark.parametrize("kernel", KERNELS)
def test_tumbling_tau_c_equals_batch_on_the_last_block(kernel):
    frames = _scene_frames(130)
    engine = SlidingWindow((24, 24), 50, 3, estimators=["tau_c"], mode="tumbling", kernel=kernel, max_lag=15)
    _feed(engine, frames)
    assert engine.blocks_completed == 2
    _assert_equal_to_batch(engine, frames[50:100])


@pytest.mark.parametrize("kernel", KERNELS)
def test_sixteen_bit_full_scale_sums_are_exact(kernel):
    """Extreme 16-bit values: the integer sums match the batch's exact ones."""
    rng = np.random.default_rng(5)
    frames = rng.choice(np.array([0, 1, 65534, 65535], np.uint16), size=(40, 4, 5))
    engine = SlidingWindow((4, 5), 30, 2, estimators=["s3", "tau_c"], kernel=kernel, max_lag=6)
    _feed(engine, frames)
    cov, var = engine._tau_covariances()
    ref_cov, ref_var = covariances(frames[-30:], 6)
    np.testing.assert_array_equal(cov, ref_cov.reshape(ref_cov.shape[0], -1))
    np.testing.assert_array_equal(var, ref_var.reshape(-1))
    _assert_equal_to_batch(engine, frames[-30:])


def test_numba_and_numpy_sums_are_bit_identical():
    if "numba" not in KERNELS:
        pytest.fail("numba is a test dependency of the project")
    frames = _scene_frames(80)
    states = []
    for kernel in KERNELS:
        engine = SlidingWindow((24, 24), 40, 4, estimators=["tau_c"], kernel=kernel)
        _feed(engine, frames)
        states.append(engine._snapshot())
    for name in states[0]:
        if isinstance(states[0][name], np.ndarray):
            np.testing.assert_array_equal(states[0][name], states[1][name])


@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_batched_products_over_many_blocks_are_bit_identical(mode):
    """Frames of 300 x 300 pixels: the parallel kernels' blocks of pixels (kernels_numba.BATCH_BLOCK,
    the last one partial) give the NumPy twin's products, batch by batch."""
    if "numba" not in KERNELS:
        pytest.fail("numba is a test dependency of the project")
    rng = np.random.default_rng(5)
    frames = np.minimum(rng.exponential(60.0, (75, 300, 300)), 255).astype(np.uint8)
    engines = [SlidingWindow((300, 300), 40, 3, estimators=["tau_c"], kernel=kernel, mode=mode, max_lag=12)
               for kernel in KERNELS]
    for frame in frames:
        for engine in engines:
            engine.push(frame)
        np.testing.assert_array_equal(engines[0]._arrays["products"], engines[1]._arrays["products"])
    assert engines[1]._parallel and frames[0].size % 8192


def test_resync_reproduces_the_lag_products():
    frames = _scene_frames(70)
    engine = SlidingWindow((24, 24), 30, 2, estimators=["s2", "tau_c"], kernel="numpy", max_lag=5)
    _feed(engine, frames)
    before = engine._snapshot()
    engine.resync()
    after = engine._snapshot()
    np.testing.assert_array_equal(before["products"], after["products"])
    np.testing.assert_array_equal(before["total_sq"], after["total_sq"])


def test_default_max_lag_and_refusals():
    assert SlidingWindow((4, 4), 200, 10, estimators=["tau_c"]).max_lag == 100  # N/2
    assert SlidingWindow((4, 4), 12, 10, estimators=["tau_c"]).max_lag == 6
    assert SlidingWindow((4, 4), 3, 1, estimators=["tau_c"]).max_lag == 1  # at most N-2
    with pytest.raises(EstimatorError, match="sliding' or 'tumbling"):
        SlidingWindow((4, 4), 50, 5, estimators=["tau_c"], mode="exponential")
    with pytest.raises(EstimatorError, match="max_lag"):
        SlidingWindow((4, 4), 50, 5, estimators=["tau_c"], max_lag=49)
    with pytest.raises(EstimatorError, match="max_lag"):
        SlidingWindow((4, 4), 50, 5, estimators=["tau_c"], max_lag=0)
    engine = SlidingWindow((4, 4), 20, 2, estimators=["s1"])
    _feed(engine, np.zeros((20, 4, 4), np.uint8))
    with pytest.raises(EstimatorError, match="tau_c"):
        engine.tau_c_bounds()
    with pytest.raises(EstimatorError, match="boolean"):
        SlidingWindow((4, 4), 20, 2, estimators=["tau_c"]).region_tau_c(np.ones((4, 4)))


def test_constant_frames_give_no_signal_not_nan():
    engine = SlidingWindow((3, 3), 20, 2, estimators=["tau_c"], mode="tumbling")
    _feed(engine, np.full((20, 3, 3), 255, np.uint8))
    result = engine.tau_c_bounds()
    assert np.all(result.tau == 0.0) and np.all(result.status == 2)
    assert tuple(engine.region_tau_c(np.ones((3, 3), bool))) == (0.0, 2)


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_streaming_equals_batch_on_degenerate_data(data):
    """Constant, saturated and zero pixels, extreme values, every lag bound: the engine's τc
    and status equal the batch ones on the same window, never NaN."""
    window = data.draw(st.integers(3, 24))
    lag = data.draw(st.integers(1, window - 1))
    lags = data.draw(st.integers(1, window - 2))
    mode = data.draw(st.sampled_from(["sliding", "tumbling"]))
    count = data.draw(st.integers(window, 2 * window + 3))
    frames = data.draw(arrays(np.uint8, (count, 2, 3), elements=st.sampled_from([0, 1, 2, 200, 254, 255])))
    engine = SlidingWindow((2, 3), window, lag, estimators=["tau_c"], mode=mode, kernel="numpy",
                           max_lag=lags)
    _feed(engine, frames)
    end = engine.blocks_completed * window if mode == "tumbling" else count
    expected = tau_c_bounds(frames[end - window:end], lags)
    got = engine.tau_c_bounds()
    assert np.isfinite(got.tau).all()
    np.testing.assert_array_equal(got.status, expected.status)
    np.testing.assert_allclose(got.tau, expected.tau, rtol=1e-9, atol=0)
