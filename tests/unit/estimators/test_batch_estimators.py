"""The paper's Eq. 1-4 against small cases worked out by hand, and the degenerate cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from edgedsm.errors import EstimatorError
from edgedsm.estimators import all_maps, s1, s2, s3, temporal_sigma


def column(*values, dtype=np.uint8):
    return np.array(values, dtype=dtype).reshape(-1, 1, 1)


def test_hand_computed_case():
    frames = column(1, 3, 2, 2)
    # lag 1: |1-3|, |3-2|, |2-2| = 2, 1, 0
    assert s1(frames, 1)[0, 0] == pytest.approx(1.0)
    assert s2(frames, 1)[0, 0] == pytest.approx((2 / 4 + 1 / 5 + 0 / 4) / 3)
    assert s2(frames, 1, q=1.0)[0, 0] == pytest.approx((2 / 5 + 1 / 6 + 0) / 3)
    # σ² = mean((I - 2)²) = (1 + 1 + 0 + 0)/4
    assert temporal_sigma(frames)[0, 0] == pytest.approx(np.sqrt(0.5))
    assert s3(frames, 1)[0, 0] == pytest.approx(1.0 / np.sqrt(0.5))
    # lag 2: |1-2|, |3-2| = 1, 1
    assert s1(frames, 2)[0, 0] == pytest.approx(1.0)
    # lag N-1 = 3: one pair |1-2|
    assert s1(frames, 3)[0, 0] == pytest.approx(1.0)
    assert s2(frames, 3)[0, 0] == pytest.approx(1 / 3)


def test_maps_are_pointwise():
    rng = np.random.default_rng(3)
    stack = rng.integers(0, 256, size=(20, 3, 4), dtype=np.uint8)
    full = all_maps(stack, 3, q=0.5)
    for r in range(3):
        for c in range(4):
            pixel = stack[:, r:r + 1, c:c + 1]
            assert full["s1"][r, c] == pytest.approx(s1(pixel, 3)[0, 0])
            assert full["s2"][r, c] == pytest.approx(s2(pixel, 3, q=0.5)[0, 0])
            assert full["s3"][r, c] == pytest.approx(s3(pixel, 3)[0, 0])


def test_zero_intensity_with_q_zero_is_zero_not_nan():
    frames = column(0, 0, 0, 5, 0)
    value = s2(frames, 1)[0, 0]
    # pairs (0,0) (0,0) (0,5) (5,0): 0 + 0 + 1 + 1
    assert value == pytest.approx(0.5)
    assert np.isfinite(s2(np.zeros((5, 2, 2), np.uint8), 1)).all()
    assert (s2(np.zeros((5, 2, 2), np.uint8), 1) == 0).all()


@pytest.mark.parametrize("value", [0, 37, 255])
def test_constant_or_saturated_pixel_gives_zero_s3(value):
    frames = np.full((10, 2, 2), value, np.uint8)
    result = s3(frames, 2)
    assert np.isfinite(result).all() and (result == 0).all()
    assert (s1(frames, 2) == 0).all()


def test_sigma_exact_for_large_offsets():
    # 16-bit values near full scale with a tiny spread: the naive float formula cancels
    frames = column(*([65534, 65535] * 50), dtype=np.uint16)
    assert temporal_sigma(frames)[0, 0] == 0.5
    floats = frames.astype(np.float64) + 1e9
    assert temporal_sigma(floats)[0, 0] == pytest.approx(0.5, rel=1e-6)


def test_sixteen_bit_full_scale_has_no_overflow():
    frames = column(*([0, 65535] * 100), dtype=np.uint16)
    assert s1(frames, 1)[0, 0] == 65535
    assert temporal_sigma(frames)[0, 0] == 65535 / 2
    assert s3(frames, 1)[0, 0] == pytest.approx(2.0)
    assert s2(frames, 1)[0, 0] == pytest.approx(1.0)


@pytest.mark.parametrize("lag", [0, 4, -1, 10])
def test_lag_must_fit_window(lag):
    with pytest.raises(EstimatorError, match="does not fit a window of N=4"):
        s1(np.zeros((4, 2, 2), np.uint8), lag)


def test_bad_arguments_are_refused_clearly():
    with pytest.raises(EstimatorError, match=r"\(N, H, W\) stack"):
        s1(np.zeros((4, 4), np.uint8), 1)
    with pytest.raises(EstimatorError, match="integer number of frames"):
        s1(np.zeros((4, 2, 2), np.uint8), 1.5)
    with pytest.raises(EstimatorError, match="q must be"):
        s2(np.zeros((4, 2, 2), np.uint8), 1, q=-1)
    with pytest.raises(EstimatorError, match="NaN or inf"):
        s1(np.full((4, 2, 2), np.nan), 1)
    with pytest.raises(EstimatorError, match="integer or float"):
        s1(np.zeros((4, 2, 2), bool), 1)


@settings(max_examples=60, deadline=None)
@given(arrays(np.uint16, st.tuples(st.integers(2, 12), st.integers(1, 3), st.integers(1, 3)),
              elements=st.integers(0, 4095)), st.data())
def test_against_a_direct_loop(stack, data):
    n = stack.shape[0]
    lag = data.draw(st.integers(1, n - 1))
    q = data.draw(st.sampled_from([0.0, 0.5, 10.0]))
    maps = all_maps(stack, lag, q=q)
    series = stack[:, 0, 0].astype(float)
    pairs = [(series[i], series[i + lag]) for i in range(n - lag)]
    expect_s1 = sum(abs(a - b) for a, b in pairs) / len(pairs)
    expect_s2 = sum(abs(a - b) / (a + b + q) if a + b + q > 0 else 0 for a, b in pairs) / len(pairs)
    sigma = series.std()
    assert maps["s1"][0, 0] == pytest.approx(expect_s1)
    assert maps["s2"][0, 0] == pytest.approx(expect_s2)
    assert maps["s3"][0, 0] == pytest.approx(expect_s1 / sigma if sigma > 0 else 0.0)
    assert all(np.isfinite(m).all() for m in maps.values())


def test_sigma_of_very_long_sixteen_bit_windows():
    # 100 000 frames of 0/max alternation: N·ΣI² no longer fits int64
    frames = np.tile(np.array([0, 65535], np.uint16), 50_000).reshape(-1, 1, 1)
    assert temporal_sigma(frames)[0, 0] == pytest.approx(65535 / 2, rel=1e-12)
    ramp = (np.arange(100_001) % 3).astype(np.uint16).reshape(-1, 1, 1) + 60000
    assert temporal_sigma(ramp)[0, 0] == pytest.approx(np.std(np.arange(100_001) % 3), rel=1e-9)


@pytest.mark.parametrize("values", [[-1.0, 3.0, -2.0, 5.0], [1.0, np.nan, 2.0, 3.0], [1.0, np.inf, 2.0, 3.0],
                                    [1.0, 2.0, -np.inf, 3.0], [0.0, -1e-300, 2.0, 3.0]])
@pytest.mark.parametrize("estimator", [s1, s2, s3, all_maps])
def test_negative_or_non_finite_float_intensities_are_refused(values, estimator):
    """Issue 9 §6: all_maps([-1, 3, -2, 5], 1) gave S2 = 3.11, above its maximum of 1."""
    frames = column(*values, dtype=np.float64)
    with pytest.raises(EstimatorError, match=r"negative|NaN or inf") as info:
        estimator(frames, 1)
    assert "\n" not in str(info.value)


def test_signed_integer_intensities_below_zero_are_refused():
    with pytest.raises(EstimatorError, match="negative"):
        all_maps(column(-1, 3, -2, 5, dtype=np.int16), 1)
    assert all_maps(column(1, 3, 2, 5, dtype=np.int16), 1)["s2"][0, 0] <= 1.0
