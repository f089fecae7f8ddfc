"""The per-pixel S1/S2/σ/S3, contrast, Fujii and IM definitions (edgedsm.estimators.activity): the
compiled functions, their NumPy twins and every kernel that forms map values agree bit for bit."""

from __future__ import annotations

import importlib.util
import math
from fractions import Fraction

import numpy as np
import pytest

from edgedsm.estimators import activity
from edgedsm.estimators.kernels_numpy import maps_kernel as numpy_maps_kernel
from edgedsm.estimators.value_set import VALUES

HAS_NUMBA = importlib.util.find_spec("numba") is not None


def window_sums(seed: int, pixels: int, n: int, bits: int) -> tuple[np.ndarray, ...]:
    """Integer sums of N random frames per pixel, with constant (σ = 0) and full-scale pixels."""
    rng = np.random.default_rng(seed)
    top = (1 << bits) - 1
    frames = rng.integers(0, top + 1, (n, pixels), dtype=np.int64)
    frames[:, 0] = top  # saturated: σ = 0
    frames[:, 1] = 0  # dark: σ = 0
    frames[::2, 2] = top  # the largest spread
    frames[1::2, 2] = 0
    abs_sum = np.abs(np.diff(frames, axis=0)).sum(axis=0)
    ratio_sum = rng.integers(0, 2**40, pixels, dtype=np.int64)
    return abs_sum, ratio_sum, frames.sum(axis=0), (frames * frames).sum(axis=0)


def sq_sums(abs_sum: np.ndarray) -> np.ndarray:
    """A Σ(ΔI)² of the size of the sums (exact integers up to 16-bit squares times N)."""
    return abs_sum * 65535 + 3


ALL = (True,) * 6


def numpy_values(exponential, abs_sum, ratio_sum, second, fourth, pairs, unit, n, weight):
    out = {name: np.empty(abs_sum.size) for name in VALUES}
    sq_sum = np.sqrt(np.abs(abs_sum)) * 3.0 if exponential else sq_sums(abs_sum)
    activity.values_numpy(exponential, ALL, abs_sum, ratio_sum, second, fourth, sq_sum, pairs, unit, n, weight, out)
    return list(out.values())


@pytest.mark.parametrize("bits", [8, 16])
def test_numpy_twins_follow_the_definitions(bits):
    """S1 and σ as exact rational arithmetic rounds them; S3 = S1/σ, 0 where σ = 0."""
    n, pairs = 50, 49
    abs_sum, ratio_sum, total, total_sq = window_sums(bits, 200, n, bits)
    s1, s2, s3, sigma, contrast, fujii, im = numpy_values(False, abs_sum, ratio_sum, total, total_sq, pairs,
                                                          2.0**-45, n, 1.0)
    for p in range(200):
        assert s1[p] == abs_sum[p] / pairs  # the correctly rounded quotient
        spread = Fraction(n * int(total_sq[p]) - int(total[p]) ** 2)
        assert abs(sigma[p] - math.sqrt(spread) / n) <= 2**-51 * sigma[p]
    assert sigma[0] == sigma[1] == 0.0 and s3[0] == s3[1] == 0.0
    assert sigma[2] == ((1 << bits) - 1) / 2
    np.testing.assert_array_equal(s3[3:], s1[3:] / sigma[3:])
    np.testing.assert_array_equal(s2, ratio_sum * 2.0**-45 / pairs)
    np.testing.assert_array_equal(fujii, 200.0 * s2)
    np.testing.assert_array_equal(im, sq_sums(abs_sum) / pairs)
    assert contrast[0] == 0.0 and contrast[1] == 0.0  # saturated: σ = 0; dark: ⟨I⟩ = 0
    np.testing.assert_array_equal(contrast[2:], sigma[2:] / (total[2:] / n))
    assert np.isfinite(np.stack([s1, s2, s3, sigma, contrast, fujii, im])).all()


@pytest.mark.skipif(not HAS_NUMBA, reason="numba not installed")
@pytest.mark.parametrize("exponential", [False, True])
@pytest.mark.parametrize("bits", [8, 16])
def test_compiled_values_equal_the_numpy_twins_bit_for_bit(exponential, bits):
    import numba

    @numba.njit
    def every_pixel(exponential, abs_sum, ratio_sum, second, fourth, sq_sum, pairs, unit, n, weight):
        out = np.empty((7, abs_sum.size))
        for p in range(abs_sum.size):
            values = activity.pixel_values(exponential, True, True, True, True, True, True, p, abs_sum, ratio_sum,
                                           second, fourth, sq_sum, pairs, unit, n, weight)
            for k in range(7):
                out[k, p] = values[k]
        return out

    n, pairs, unit = 60, 55, 2.0**-46
    abs_sum, ratio_sum, total, total_sq = window_sums(3 + bits, 300, n, bits)
    if exponential:  # float64 means and M2 (0 for the first pixel: σ = 0)
        rng = np.random.default_rng(bits)
        abs_sum = rng.random(300) * 40.0
        ratio_sum = rng.random(300)
        total = total_sq = np.where(np.arange(300) == 0, 0.0, rng.random(300) * 1e4)
    sq_sum = np.sqrt(np.abs(abs_sum)) * 3.0 if exponential else sq_sums(abs_sum)
    compiled = every_pixel(exponential, abs_sum, ratio_sum, total, total_sq, sq_sum, pairs, unit, n, 37.5)
    twin = numpy_values(exponential, abs_sum, ratio_sum, total, total_sq, pairs, unit, n, 37.5)
    np.testing.assert_array_equal(compiled, np.stack(twin))
    assert np.isfinite(compiled).all()
    for parallel in (False, True):  # the maps kernel of both kernel modules: the same values again
        from edgedsm.estimators.kernels_numba import maps_kernel

        out = [np.empty(300) for _ in range(7)]
        maps_kernel(True, True, True, parallel, exponential, True, True, True)(
            abs_sum, ratio_sum, total, total_sq, sq_sum, pairs, unit, n, *out, 37.5)
        np.testing.assert_array_equal(np.stack(out), compiled)
    out = [np.empty(300) for _ in range(7)]
    numpy_maps_kernel(True, True, True, False, exponential, True, True, True)(
        abs_sum, ratio_sum, total, total_sq, sq_sum, pairs, unit, n, *out, 37.5)
    np.testing.assert_array_equal(np.stack(out), compiled)


def test_sigma_beyond_int64_takes_the_float_branch_in_both():
    n = 2**21
    total = np.array([n // 2 * 65535, n * 30000 + 12345], np.int64)
    total_sq = np.array([n // 2 * 65535**2, n * 30000**2 + 12345 * 60001], np.int64)
    sigma = activity.window_sigmas(total, total_sq, n)
    assert sigma[0] == 32767.5
    exact = math.sqrt(Fraction(n * int(total_sq[1]) - int(total[1]) ** 2, n * n))
    assert abs(sigma[1] - exact) <= 2**-50 * exact
    if HAS_NUMBA:
        assert [activity.window_sigma(t, q, n) for t, q in zip(total, total_sq, strict=True)] == sigma.tolist()
