"""The batch descriptors of edgedsm.estimators.descriptors against brute-force definitions (BSLTL's
loops written out) on small random stacks, 8 and 16 bits."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from edgedsm.errors import EstimatorError
from edgedsm.estimators import s1, s2, temporal_sigma
from edgedsm.estimators.descriptors import (
    BSLTL_EPS,
    DESCRIPTORS,
    compute,
    contrast,
    fujii,
    gd,
    im,
    kurtosis,
    mhi,
    skewness,
)


def _stack(dtype: type, n: int = 17, seed: int = 3) -> np.ndarray:
    top = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, top + 1, (n, 5, 6)).astype(dtype)


def _gd_pairs(stack: np.ndarray) -> np.ndarray:
    """BSLTL gendiff.m as written: every pair, O(N²)."""
    data = stack.astype(np.float64)
    total = np.zeros(stack.shape[1:])
    for i, j in itertools.combinations(range(len(stack)), 2):
        total += np.abs(data[i] - data[j])
    return total / math.comb(len(stack), 2)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("n", [2, 3, 17, 40])
def test_gd_is_the_mean_over_all_pairs(dtype: type, n: int) -> None:
    stack = _stack(dtype, n)
    # integer sums are exact on both sides (< 2^53): equal to the last bit
    np.testing.assert_array_equal(gd(stack), _gd_pairs(stack))


def test_gd_of_float_data_and_of_ties() -> None:
    rng = np.random.default_rng(5)
    stack = rng.uniform(0, 1000, (23, 4, 3))
    np.testing.assert_allclose(gd(stack), _gd_pairs(stack), rtol=1e-13)
    ties = np.array([3, 3, 7, 3, 7], np.uint8).reshape(5, 1, 1)  # 6 pairs of |3-7| = 4 out of 10
    assert gd(ties)[0, 0] == pytest.approx(6 * 4 / 10, abs=0)


def test_gd_of_float_data_on_a_large_offset() -> None:
    # 1e6 ± 1e-3: summing x_(k) with weights ±N would lose ~1e6/1e-3 · 2^-53 ≈ 1e-7 relative;
    # taken off the minimum first, it keeps the pairwise loop's accuracy
    stack = 1e6 + np.random.default_rng(9).uniform(0, 1e-3, (40, 3, 3))
    np.testing.assert_allclose(gd(stack), _gd_pairs(stack - 1e6), rtol=1e-9)


@settings(max_examples=50, deadline=None)
@given(arrays(np.uint16, st.tuples(st.integers(2, 9), st.integers(1, 3), st.integers(1, 3)),
              elements=st.sampled_from([0, 1, 2, 65534, 65535])))
def test_gd_equals_the_pairs_on_extreme_and_tied_values(stack: np.ndarray) -> None:
    np.testing.assert_array_equal(gd(stack), _gd_pairs(stack))


def test_gd_of_two_frames_is_s1() -> None:
    stack = _stack(np.uint16, 2)
    np.testing.assert_array_equal(gd(stack), s1(stack, 1))


@pytest.mark.parametrize("lag", [1, 4])
def test_fujii_is_200_s2_with_bsltl_eps(lag: int) -> None:
    stack = _stack(np.uint8, 30)
    np.testing.assert_array_equal(fujii(stack, lag), 200 * s2(stack, lag, q=BSLTL_EPS))
    # and q = 0 (the 200·S2) differs only in the last bits, where I_k + I_{k+m} = 1
    np.testing.assert_allclose(fujii(stack, lag), 200 * s2(stack, lag), rtol=1e-15)


def test_fujii_by_its_bsltl_loop() -> None:
    stack = _stack(np.uint8, 12).astype(np.float64)
    stack[:, 0, 0] = 0  # a dark pixel: 0/(0 + eps) = 0 in BSLTL too
    expected = np.zeros(stack.shape[1:])
    for k in range(len(stack) - 1):
        expected += np.abs(stack[k] - stack[k + 1]) / (stack[k] + stack[k + 1] + BSLTL_EPS)
    np.testing.assert_allclose(fujii(stack), expected * 200 / (len(stack) - 1), rtol=1e-14)
    assert fujii(stack)[0, 0] == 0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("lag", [1, 3])
def test_im_is_the_mean_squared_difference(dtype: type, lag: int) -> None:
    stack = _stack(dtype, 25)
    data = stack.astype(np.float64)
    # exact: the int64 sum is below 2^53 here, as is each float64 partial sum
    expected = sum((data[k] - data[k + lag]) ** 2 for k in range(len(data) - lag)) / (len(data) - lag)
    np.testing.assert_array_equal(im(stack, lag), expected)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_contrast_skewness_kurtosis_against_their_definitions(dtype: type) -> None:
    stack = _stack(dtype, 31)
    data = stack.astype(np.float64)
    mean = data.mean(axis=0)
    sigma = np.sqrt(((data - mean) ** 2).mean(axis=0))
    np.testing.assert_allclose(contrast(stack), sigma / mean, rtol=1e-13)
    np.testing.assert_allclose(contrast(stack), temporal_sigma(stack) / mean, rtol=1e-15)
    z = (data - mean) / sigma
    np.testing.assert_allclose(skewness(stack), (z**3).mean(axis=0), rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(kurtosis(stack), (z**4).mean(axis=0), rtol=1e-12)


def test_skewness_and_kurtosis_of_known_series() -> None:
    # 0, 0, 0, 4: mean 1, deviations -1,-1,-1,3; σ² = 3; m3 = 6, m4 = 21
    series = np.array([0, 0, 0, 4], np.uint8).reshape(4, 1, 1)
    assert skewness(series)[0, 0] == pytest.approx(6 / 3**1.5, rel=1e-15)
    assert kurtosis(series)[0, 0] == pytest.approx(21 / 9, rel=1e-15)
    assert contrast(series)[0, 0] == pytest.approx(math.sqrt(3), rel=1e-15)


def test_mhi_weights_later_changes_more() -> None:
    # 5 frames, 4 transitions weighted 255 j / 10; changes > 2 at j = 1 and j = 4 only
    series = np.array([0, 9, 10, 10, 0], np.uint8).reshape(5, 1, 1)
    assert mhi(series, 2)[0, 0] == pytest.approx(255 * (1 + 4) / 10, rel=1e-15)
    assert mhi(series, 10)[0, 0] == 0  # strictly greater than U, as graphmhi's S > U
    with pytest.raises(EstimatorError, match="threshold"):
        mhi(series, -1)


def test_the_registry_computes_every_name() -> None:
    stack = _stack(np.uint8, 16)
    for name, descriptor in DESCRIPTORS.items():
        result = compute(name, stack, lag=2, threshold=20.0, dt=0.1)
        assert result.shape == (5, 6) and result.dtype == np.float64 and np.isfinite(result).all(), name
        assert descriptor.unit and descriptor.streaming and descriptor.summary
    np.testing.assert_array_equal(compute("fujii", stack, lag=2), fujii(stack, 2))
    np.testing.assert_array_equal(compute("gd", stack, lag=2), gd(stack))
    with pytest.raises(EstimatorError, match="mhi needs --threshold"):
        compute("mhi", stack)
    with pytest.raises(EstimatorError, match="unknown descriptor"):
        compute("nope", stack)


@pytest.mark.parametrize("function", [gd, contrast, skewness, kurtosis])
def test_one_frame_is_refused(function) -> None:
    with pytest.raises(EstimatorError, match="N >= 2"):
        function(np.zeros((1, 3, 3), np.uint8))
    with pytest.raises(EstimatorError, match="negative"):
        function(-np.ones((3, 3, 3)))
